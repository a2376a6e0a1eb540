#include "formats/convert.h"

#include <cmath>
#include <filesystem>
#include <fstream>
#include <stdexcept>

#include "brdf/astm.h"
#include "brdf/merl.h"
#include "brdf/model.h"
#include "brdf/rgl.h"
#include "brdf/utia.h"
#include "data_synth/table_io.h"

namespace brdfkit::formats {

std::string FormatName(Format f) {
  switch (f) {
    case Format::kMerl: return "merl";
    case Format::kRgl: return "rgl";
    case Format::kUtia: return "utia";
    case Format::kAstm: return "astm";
    case Format::kCsv: return "csv";
  }
  return "?";
}

Format FormatOfName(const std::string& path) {
  std::string ext = std::filesystem::path(path).extension().string();
  for (char& c : ext) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  if (ext == ".binary") return Format::kMerl;
  if (ext == ".bsdf") return Format::kRgl;
  if (ext == ".utia" || ext == ".bin") return Format::kUtia;
  if (ext == ".astm") return Format::kAstm;
  if (ext == ".csv") return Format::kCsv;
  throw std::invalid_argument("'" + path + "': unknown extension '" + ext +
                              "' (expected .binary MERL, .bsdf RGL, .utia or .bin UTIA, .astm ASTM E1392, .csv brdfkit table)");
}

Format DetectFormat(const std::string& path) {
  const Format f = FormatOfName(path);
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error("cannot read '" + path + "'");
  char head[12] = {};
  in.read(head, 12);
  const std::streamsize got = in.gcount();
  const bool tensor = got == 12 && std::string(head, 12) == std::string("tensor_file\0", 12);
  std::error_code ec;
  const auto size = std::filesystem::file_size(path, ec);
  auto mismatch = [&](const std::string& what) {
    throw std::runtime_error("'" + path + "' is named as " + FormatName(f) + " but " + what);
  };
  if (f == Format::kRgl && !tensor) mismatch("does not start with \"tensor_file\"");
  if (f != Format::kRgl && tensor) mismatch("is a tensor file (RGL, .bsdf)");
  if (f == Format::kUtia && size != UtiaTable::kFileSize)
    mismatch("is " + std::to_string(size) + " bytes, not the UTIA size " + std::to_string(UtiaTable::kFileSize));
  if (f == Format::kMerl && size == UtiaTable::kFileSize) mismatch("has the UTIA size (rename it .utia)");
  return f;
}

Source LoadSource(const std::string& path) {
  Source s;
  s.format = DetectFormat(path);
  auto from_model = [&](const std::string& name) {
    auto model = std::make_shared<const Model>(Model::Parse(name, Settings{{"path", path}}));
    auto bxdf = std::shared_ptr<const Bxdf<double>>(model->Make<double>().release());
    s.keep = bxdf;
    s.f = [bxdf](const Eigen::Vector3d& wi, const Eigen::Vector3d& wo) { return bxdf->Eval(nullptr, wi, wo); };
  };
  auto varying_phi = [](const std::vector<AngleSample>& rows) {
    for (const AngleSample& r : rows)
      if (r.theta_i > 1e-12 && std::abs(r.phi_i - rows.front().phi_i) > 1e-9) return true;
    return false;
  };
  switch (s.format) {
    case Format::kMerl: from_model("merl"); break;
    case Format::kRgl: {
      from_model("rgl");
      s.anisotropic = !RglBsdf::Read(path).isotropic;
      break;
    }
    case Format::kUtia: from_model("utia"); s.anisotropic = true; break;
    case Format::kAstm: {
      from_model("astm");
      s.anisotropic = varying_phi(AstmTable::Read(path).rows);
      break;
    }
    case Format::kCsv: {
      const synth::BrdfTable t = synth::ReadTableCsv(path);
      if (t.rows.empty()) throw std::runtime_error("CSV table '" + path + "' holds no samples");
      std::vector<AngleSample> rows;
      for (const auto& r : t.rows) rows.push_back({r.theta_i, r.phi_i, r.theta_o, r.phi_o, r.f});
      s.anisotropic = varying_phi(rows);
      auto cloud = std::make_shared<const SampleCloud>(rows);
      s.keep = cloud;
      s.f = [cloud](const Eigen::Vector3d& wi, const Eigen::Vector3d& wo) { return cloud->Lookup(wi, wo, 1); };
      break;
    }
  }
  return s;
}

bool IsAnisotropic(const BrdfFunction& f) {
  for (double turn : {0.9, 2.3}) {
    const Eigen::Matrix3d r = Eigen::AngleAxisd(turn, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    if (!InvariantUnder(f, [&r](const Eigen::Vector3d& w) { return Eigen::Vector3d(r * w); })) return true;
  }
  return false;
}

nlohmann::json ModelSource(const BrdfFunction& f, const std::string& spec, const std::string& params,
                           ConvertOptions& options) {
  const bool anisotropic = IsAnisotropic(f);
  options.anisotropic = options.anisotropic || anisotropic;
  return {{"model", spec}, {"params", params}, {"anisotropic", anisotropic}};
}

RglOptions RglTarget(const ConvertOptions& o) {
  RglOptions r = o.rgl;
  if (r.phi_i < 0) r.phi_i = o.anisotropic ? RglAnisotropicSlices(r.symmetry) : 0;
  return WithDefaults(r);
}

nlohmann::json WriteFormat(const std::string& path, const BrdfFunction& f, const ConvertOptions& o) {
  const Format format = FormatOfName(path);
  nlohmann::json j;
  j["path"] = path;
  j["format"] = FormatName(format);
  switch (format) {
    case Format::kMerl: {
      MerlTable::FromFunction(f).Write(path);
      j["resolution"] = {{"theta_h", 90}, {"theta_d", 90}, {"phi_d", 180}};
      j["note"] = "isotropic: tabulated at phi_h = 0";
      if (o.anisotropic)
        j["warning"] = "the source is anisotropic and MERL isotropic: tabulated at phi_h = 0, the variation with "
                       "phi_h is lost";
      break;
    }
    case Format::kUtia: {
      UtiaTable::FromFunction(f).Write(path);
      j["resolution"] = {{"theta", 6}, {"phi", 48}};
      break;
    }
    case Format::kRgl: {
      const RglOptions r = RglTarget(o);
      const TensorFile t = MakeRgl(f, r);
      const RglBsdf back = RglBsdf::FromTensors(t, "RGL file '" + path + "'");
      const RglAccuracy acc = MeasureRglAccuracy(back, f), grazing = MeasureRglAccuracyTowardsGrazing(back, f);
      t.Write(path);
      j["resolution"] = {{"theta_i", r.theta_i}, {"theta_max_deg", r.theta_max_deg}, {"phi_i", r.phi_i},
                         {"symmetry", r.symmetry},
                         {"ndf", r.ndf}, {"sigma", r.sigma}, {"vndf", r.vndf}, {"vndf_theta", r.vndf_theta}, {"samples", r.samples}};
      j["isotropic"] = r.phi_i == 0;
      const auto accuracy = [](const RglAccuracy& a) {
        return nlohmann::json{{"max_relative", a.max_relative}, {"p99_relative", a.p99_relative},
                              {"mean_relative", a.mean_relative}, {"points", a.points}, {"where", a.where}};
      };
      j["reconstruction"] = accuracy(acc);
      j["reconstruction_towards_grazing"] = accuracy(grazing);
      j["reconstruction_towards_grazing"]["beyond"] =
          "beyond theta_i = " + FormatDouble(r.theta_max_deg) + " deg the format's readers hold the last slice";
      break;
    }
    case Format::kAstm:
    case Format::kCsv: {
      if (!(o.step_deg >= 0.5 && o.step_deg <= 45)) throw std::invalid_argument("--step must be 0.5 to 45 degrees");
      const int phi_i = o.phi_i >= 0 ? std::max(o.phi_i, 1) : (o.anisotropic ? 8 : 1);
      const double deg = kPi / 180;
      std::vector<AngleSample> rows;
      for (double ti = 0; ti <= 85 + 1e-9; ti += o.step_deg)
        for (int a = 0; a < phi_i; ++a)
          for (double to = 0; to <= 85 + 1e-9; to += o.step_deg)
            for (double po = 0; po < 360 - 1e-9; po += o.step_deg) {
              AngleSample s{ti * deg, 2 * kPi * a / phi_i, to * deg, po * deg, Rgb<double>::Zero()};
              s.f = f(SphericalDirection(s.theta_i, s.phi_i), SphericalDirection(s.theta_o, s.phi_o));
              rows.push_back(s);
            }
      if (format == Format::kAstm) {
        AstmTable t;
        t.keywords = {{"SOURCE", "brdfkit"}, {"COMMENT", "f_r in 1/sr, angles in radians"}};
        t.rows = rows;
        t.Write(path);
      } else {
        synth::BrdfTable t;
        for (const AngleSample& s : rows) t.rows.push_back({s.theta_i, s.phi_i, s.theta_o, s.phi_o, s.f, Eigen::Array3d::Zero()});
        synth::WriteTableCsv(path, t);
      }
      j["resolution"] = {{"step_deg", o.step_deg}, {"phi_i", phi_i}, {"theta_max_deg", 85}, {"rows", rows.size()}};
      break;
    }
  }
  return j;
}

}  // namespace brdfkit::formats
