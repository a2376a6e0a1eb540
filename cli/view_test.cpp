// brdfkit view: the data the explorer page draws are brdfkit's values on the
// documented grids.
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <cmath>
#include <cstring>
#include <string>
#include <vector>

#include "brdf/model.h"
#include "tests/cli_util.h"

namespace {

using brdfkit::test::Brdfkit;
using brdfkit::test::CliRun;
using json = nlohmann::json;

std::vector<float> DecodeFloats(const std::string& b64) {
  std::string bytes;
  unsigned v = 0;
  int bits = 0;
  for (char c : b64) {
    const char* k = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    const char* p = std::strchr(k, c);
    if (c == '=' || p == nullptr) break;
    v = (v << 6) | unsigned(p - k);
    bits += 6;
    if (bits >= 8) {
      bits -= 8;
      bytes += char((v >> bits) & 0xff);
    }
  }
  std::vector<float> out(bytes.size() / sizeof(float));
  std::memcpy(out.data(), bytes.data(), out.size() * sizeof(float));
  return out;
}

json PageData(const std::string& html) {
  const std::string open = "<script type=\"application/json\" id=\"brdf-explorer-data\">";
  const auto a = html.find(open), b = html.find("</script>", a);
  return json::parse(html.substr(a + open.size(), b - a - open.size()));
}

// Lambert is rho/pi everywhere above the horizon and isotropic (one phi_i);
// anisotropic GGX is stored every 30 degrees of phi_i.
TEST(View, EmbedsTheModelValuesOnTheGrids) {
  const auto dir = brdfkit::test::FreshDir("view");
  const std::string page = (dir / "page.html").string();
  const CliRun r = Brdfkit("view lambert:albedo=0.1:0.2:0.3 ggx_aniso:alpha_x=0.3,alpha_y=0.1 --out " + page);
  ASSERT_EQ(r.code, 0) << r.out;
  const std::string html = brdfkit::test::ReadText(page);
  EXPECT_EQ(html.find("http"), std::string::npos) << "no network";
  const json d = PageData(html);
  ASSERT_EQ(d["materials"].size(), 2u);
  const json& lambert = d["materials"][0];
  EXPECT_EQ(lambert["label"], "lambert:albedo=0.1:0.2:0.3");
  EXPECT_EQ(lambert["phi_i_deg"].size(), 1u);
  const std::size_t nt = d["theta_i_deg"].size(), ns = d["slice_deg"].size();
  EXPECT_EQ(nt, 45u);
  EXPECT_EQ(ns, 179u);
  const std::vector<float> in_plane = DecodeFloats(lambert["in_plane"]);
  ASSERT_EQ(in_plane.size(), nt * ns * 3);
  for (std::size_t k = 0; k < in_plane.size(); ++k)
    ASSERT_NEAR(in_plane[k], 0.1 * (k % 3 + 1) / brdfkit::kPi, 1e-8) << k;
  // E of Lambert is rho.
  const std::vector<float> albedo = DecodeFloats(lambert["albedo"]);
  ASSERT_EQ(albedo.size(), nt * 3);
  for (std::size_t k = 0; k < albedo.size(); ++k) EXPECT_NEAR(albedo[k], 0.1 * (k % 3 + 1), 1e-6) << k;
  const json& aniso = d["materials"][1];
  EXPECT_EQ(aniso["phi_i_deg"], json({0, 30, 60, 90, 120, 150, 180}));
  EXPECT_EQ(DecodeFloats(aniso["lobe"]).size(),
            7 * nt * d["lobe_theta_deg"].size() * d["lobe_phi_deg"].size() * 3);
}

TEST(View, RejectsABadMaterialNamingTheParameter) {
  const CliRun r = Brdfkit("view ggx:alfa=0.2 --out /dev/null");
  EXPECT_EQ(r.code, 2) << r.out;
  EXPECT_NE(r.out.find("alfa"), std::string::npos) << r.out;
  const CliRun none = Brdfkit("view --out /dev/null");
  EXPECT_NE(none.code, 0);
}

}  // namespace
