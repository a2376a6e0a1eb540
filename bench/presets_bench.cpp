// The renderers' table sets (`brdfkit albedo --preset`) against Monte Carlo
// at the renderers' own sample counts, in one run:
//  - filament: brdfkit's 128 x 128 DFG table at 1e-7, then Filament's own
//    estimator (libs/ibl CubemapIBL: 1024 Hammersley points through GGX
//    normal sampling for R and G, 4096 uniform half vectors for the cloth
//    term B) over every texel; the achieved error of the estimator is its
//    difference to brdfkit's table.
//  - cycles: brdfkit's eight tables at 1e-7, then visible-normal Monte Carlo
//    with Owen-scrambled Sobol' points at Cycles' counts (2^23 per E entry,
//    2^26 per E_avg entry with mu drawn per sample, 2^20 per
//    generalised-Schlick entry) on 8 entries of each table (2 of the E_avg
//    tables), drawn at random among those not given in closed form;
//    the glass estimator weighs reflection by F and refraction by 1 - F in
//    every sample instead of choosing one (less variance than Cycles' own).
//    The time of a whole table is the measured time per entry times its
//    entries.
// Prints a Markdown table. CPU seconds are the process's, over all threads.
#include <cmath>
#include <cstdio>
#include <ctime>
#include <chrono>
#include <functional>
#include <string>
#include <vector>

#include "brdf/microfacet.h"
#include "validate/presets.h"
#include "validate/sobol.h"

namespace {

using namespace brdfkit;
using Eigen::Vector3d;

double Now() { return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count(); }
double Cpu() { return double(std::clock()) / CLOCKS_PER_SEC; }

// --- Filament's estimator --------------------------------------------------

double RadicalInverse(std::uint32_t i) {
  i = (i << 16) | (i >> 16);
  i = ((i & 0x55555555u) << 1) | ((i & 0xAAAAAAAAu) >> 1);
  i = ((i & 0x33333333u) << 2) | ((i & 0xCCCCCCCCu) >> 2);
  i = ((i & 0x0F0F0F0Fu) << 4) | ((i & 0xF0F0F0F0u) >> 4);
  i = ((i & 0x00FF00FFu) << 8) | ((i & 0xFF00FF00u) >> 8);
  return double(i) * 0x1p-32;
}

std::array<double, 3> FilamentTexel(double nov, double a) {
  const Vector3d v(std::sqrt(1 - nov * nov), 0, nov);
  double r = 0, g = 0, b = 0;
  const int n = 1024;
  for (int i = 0; i < n; ++i) {
    const double u0 = double(i) / n, u1 = RadicalInverse(i);
    const double phi = 2 * kPi * u0, ct2 = (1 - u1) / (1 + (a * a - 1) * u1), ct = std::sqrt(ct2), st = std::sqrt(1 - ct2);
    const Vector3d h(st * std::cos(phi), st * std::sin(phi), ct);
    const Vector3d l = 2 * v.dot(h) * h - v;
    const double nol = std::max(0.0, l.z()), voh = std::max(0.0, v.dot(h)), noh = std::max(0.0, h.z());
    if (nol <= 0) continue;
    const double a2 = a * a;
    const double vis = 0.5 / (nol * std::sqrt(nov * nov * (1 - a2) + a2) + nov * std::sqrt(nol * nol * (1 - a2) + a2));
    const double w = vis * nol * voh / noh, fc = std::pow(1 - voh, 5);
    r += w * fc;
    g += w;
  }
  const int m = 4096;
  for (int i = 0; i < m; ++i) {
    const double u0 = double(i) / m, u1 = RadicalInverse(i);
    const double phi = 2 * kPi * u0, ct = 1 - u1, st = std::sqrt(1 - ct * ct);
    const Vector3d h(st * std::cos(phi), st * std::sin(phi), ct);
    const Vector3d l = 2 * v.dot(h) * h - v;
    const double nol = std::max(0.0, l.z()), voh = std::max(0.0, v.dot(h)), noh = std::max(0.0, h.z());
    if (nol <= 0) continue;
    const double dc = (2 + 1 / a) * std::pow(1 - noh * noh, 0.5 / a) / (2 * kPi);
    const double vn = 1 / (4 * (nol + nov - nol * nov));
    b += vn * dc * nol * voh;
  }
  return {4 * r / n, 4 * g / n, 8 * kPi * b / m};
}

// --- Cycles-style visible-normal Monte Carlo --------------------------------

double G2OverG1(double a, const Vector3d& wi, const Vector3d& wo) {
  const double li = LambdaGgx<double>(wi, a, a), lo = LambdaGgx<double>(wo, a, a);
  return (1 + li) / (1 + li + lo);
}

// One sample's score for entry kind `table` at (roughness r, mu, z).
double Score(const std::string& table, double r, double mu, double z, double u1, double u2) {
  const double a = r * r;
  const Vector3d wi(std::sqrt(std::max(0.0, 1 - mu * mu)), 0, mu);
  const Vector3d h = SampleGgxVisibleNormal(a, a, wi, u1, u2);
  const double c = wi.dot(h);
  if (c <= 0) return 0;
  const Vector3d wr = 2 * c * h - wi;
  const double ior = (1 + z * z) / (1 - z * z);
  if (table.find("glass") != std::string::npos) {
    const double eta = table.find("inv") != std::string::npos ? 1 / ior : ior;
    const double f = FresnelDielectric(eta, c);
    double s = wr.z() > 0 ? f * G2OverG1(a, wi, wr) : 0;
    const double s2 = (1 - c * c) / (eta * eta);
    if (s2 < 1) {
      const Vector3d wt = (c / eta - std::sqrt(1 - s2)) * h - wi / eta;
      if (wt.z() < 0) s += (1 - f) * G2OverG1(a, wi, wt);
    }
    return s;
  }
  if (wr.z() <= 0) return 0;
  if (table == "table_ggx_gen_schlick_ior_s") {
    const double f0 = std::pow((ior - 1) / (ior + 1), 2);
    return std::clamp((FresnelDielectric(ior, c) - f0) / (1 - f0), 0.0, 1.0);
  }
  if (table == "table_ggx_gen_schlick_s") return std::pow(1 - c, 5 * (1 - z) / z);
  return G2OverG1(a, wi, wr);
}

}  // namespace

int main() {
  std::printf("| table set | method | samples per entry | wall s | CPU s | max abs error | RMS error |\n");
  std::printf("|---|---|---|---|---|---|---|\n");
  // Filament.
  double t0 = Now(), c0 = Cpu();
  const validate::Preset fil = validate::BuildPreset("filament");
  std::printf("| filament 128x128 RGB | brdfkit adaptive, 1e-7 | adaptive | %.2f | %.2f | %.1e (estimate) | |\n",
              Now() - t0, Cpu() - c0, fil.max_error);
  const validate::PresetTable& dfg = fil.tables[0];
  const std::size_t n = dfg.axes[0].coordinate.size();
  t0 = Now();
  c0 = Cpu();
  std::vector<double> mc(dfg.value.size());
  for (std::size_t j = 0; j < n; ++j)
    for (std::size_t i = 0; i < n; ++i) {
      const double r = dfg.axes[1].evaluated[j];
      const auto t = FilamentTexel(dfg.axes[0].evaluated[i], r * r);
      for (int ch = 0; ch < 3; ++ch) mc[3 * (j * n + i) + ch] = t[ch];
    }
  const double mc_wall = Now() - t0, mc_cpu = Cpu() - c0;
  for (int ch = 0; ch < 3; ++ch) {
    double worst = 0, sq = 0;
    for (std::size_t k = ch; k < mc.size(); k += 3) {
      worst = std::max(worst, std::abs(mc[k] - dfg.value[k]));
      sq += std::pow(mc[k] - dfg.value[k], 2);
    }
    std::printf("| filament %c | Filament's estimator (Hammersley) | %d | %.2f | %.2f | %.1e | %.1e |\n", "RGB"[ch],
                ch < 2 ? 1024 : 4096, mc_wall, mc_cpu, worst, std::sqrt(sq / (mc.size() / 3)));
  }
  // Cycles.
  t0 = Now();
  c0 = Cpu();
  const validate::Preset cyc = validate::BuildPreset("cycles");
  std::printf("| cycles, 8 tables | brdfkit adaptive, 1e-7 | adaptive | %.2f | %.2f | %.1e (estimate) | |\n",
              Now() - t0, Cpu() - c0, cyc.max_error);
  const validate::Sobol2D sobol;
  double mc_total = 0;
  for (const validate::PresetTable& t : cyc.tables) {
    const bool average = t.name.find("Eavg") != std::string::npos;
    const bool schlick = t.name.find("schlick") != std::string::npos;
    const std::uint32_t samples = average ? 1u << 26 : schlick ? 1u << 20 : 1u << 23;
    const std::size_t nodes = t.nodes();
    double worst = 0, sq = 0, seconds = 0;
    const int picks = average ? 2 : 8;  // an E_avg entry costs 8 E entries
    std::uint64_t trial = 0;
    for (int pick = 0; pick < picks; ++pick) {
      // Entries drawn at random, away from the closed-form ones (roughness
      // node 0, the matched index at z node 0), which both methods get exactly.
      std::size_t node = 0;
      std::vector<double> at;
      for (bool singular = true; singular;) {
        node = validate::Mix64(++trial) % nodes;
        std::size_t rest = node;
        at.clear();
        singular = false;
        for (const validate::PresetAxis& ax : t.axes) {
          const std::size_t i = rest % ax.coordinate.size();
          singular = singular || (i == 0 && ax.name != "mu");
          at.push_back(ax.evaluated[i]);
          rest /= ax.coordinate.size();
        }
      }
      // Axes: roughness, then mu (E tables), then z; E_avg tables have no mu.
      const double r = at[0];
      const double z = t.axes.back().name == "z" ? at.back() : 0.5;
      const double s0 = Now();
      double sum = 0;
      for (std::uint32_t k = 0; k < samples; ++k) {
        const auto u = sobol.Point(k, node + 1);
        if (average) {
          // mu independent of the Sobol' point (a hash of the index, not its bits reversed).
          const double mu = std::max(1e-9, double(validate::Mix64(k + 0x51ed27u * (node + 1)) >> 11) * 0x1p-53);
          sum += 2 * mu * Score(t.name, r, mu, z, u[0], u[1]);
        } else {
          sum += Score(t.name, r, at[1], z, u[0], u[1]);
        }
      }
      seconds += Now() - s0;
      const double e = std::abs(sum / samples - t.value[node]);
      worst = std::max(worst, e);
      sq += e * e;
    }
    const double table_s = seconds / picks * double(nodes);
    mc_total += table_s;
    std::printf("| %s (%zu entries) | visible-normal Monte Carlo, %d entries | 2^%d | %.1f (whole table, from %.2f s per entry) | | %.1e | %.1e |\n",
                t.name.c_str(), nodes, picks, int(std::log2(double(samples)) + 0.5), table_s, seconds / picks, worst,
                std::sqrt(sq / picks));
  }
  std::printf("| cycles, 8 tables | visible-normal Monte Carlo at Cycles' counts | | %.0f (one thread, from the entries measured) | | | |\n",
              mc_total);
  return 0;
}
