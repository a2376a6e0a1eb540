// The albedo tables production renderers ship, computed by the adaptive
// rule of validate/albedo.h on the renderers' own nodes, with their meaning
// and array layout, each entry with an error estimate.
//
// "cycles": every microfacet table of Blender Cycles' src/scene/shader.tables
// (made there by src/app/cycles_precompute.cpp with 2^20 to 2^26 Monte Carlo
// samples per entry):
//   table_ggx_E[32 x 32]               E(roughness, mu) of GGX reflection, F = 1
//   table_ggx_Eavg[32]                 E_avg(roughness) = 2 int_0^1 E mu dmu
//   table_ggx_glass_E[16 x 16 x 16]    E_R + E_T of rough glass, eta = ior(z)
//   table_ggx_glass_Eavg[16 x 16]      its average over mu
//   table_ggx_glass_inv_E, _inv_Eavg   the same seen from inside, eta = 1 / ior(z)
//   table_ggx_gen_schlick_ior_s        mean of s(h) = (F(wi.h, eta) - F0) / (1 - F0)
//                                      over the visible normals, reflections that
//                                      leave above the surface only
//   table_ggx_gen_schlick_s            the same for s(h) = (1 - wi.h)^e, e = 5 (1 - z) / z
// x = roughness runs fastest, then mu, then z; nodes k / (N - 1). alpha =
// roughness^2, GGX with height-correlated Smith masking. The entries are
// evaluated where Cycles' generator evaluates them: mu and roughness at
// least 1e-4, z in [1e-4, 0.99], ior(z) = (1 + z^2) / (1 - z^2) (z = F0^(1/4)).
// Where the generator takes the smooth limit (roughness node 0, alpha^2 <=
// 5e-7) or an index-matched interface (z node 0 of the ior axis, |ior - 1| <
// 1e-4), so does brdfkit, in closed form: a mirror reflects everything (E =
// 1), a smooth dielectric reflects F and transmits 1 - F (E = 1), and s is
// s(h = n).
//
// "filament": Google Filament's split-sum DFG texture (libs/ibl
// CubemapIBL::DFG, written by cmgen --ibl-dfg-multiscatter --ibl-dfg-cloth),
// N x N texels (128), RGB, NoV = (i + 0.5) / N running fastest, row j at
// perceptual roughness min(1, (j + 1.5) / N), alpha = roughness^2:
//   R = int f_ss(F = (1 - v.h)^5) NoL dl, G = int f_ss(F = 1) NoL dl (GGX,
//   height-correlated Smith), B = int D_Charlie V_Neubelt NoL dl (the cloth
//   lobe: Estevez & Kulla 2017, Neubelt & Pettineo 2013).
//
// "kulla_conty": Kulla & Conty 2017's energy compensation of rough glass
// (ggx_glass_correlated), N nodes per axis k / (N - 1) (PresetOptions::size,
// default 16) of roughness, mu and z as Cycles' glass tables:
//   kc_glass_E, kc_glass_inv_E          E_R + E_T, eta = ior(z) and 1 / ior(z)
//   kc_glass_Eavg, kc_glass_inv_Eavg    their averages over mu
//   kc_Favg, kc_inv_Favg                F_avg of the exact Fresnel term, both sides
//   kc_x                                x = t / (1 + t), t = eta^2 (1 - F_avg(1/eta))
//                                       (1 - E_avg(1/eta)) / ((1 - F_avg(eta)) (1 - E_avg(eta))):
//                                       the transmitted share of the multiple scattering
// x is 1/2 at z node 0 (matched index) and repeats node 1 at roughness 0,
// where nothing is lost. x is derived (PresetTable::derived): a ratio of
// losses L = 1 - E_avg, its error is about tol x (1 - x) (1 / L_in + 1 /
// L_out), above tol where the losses are small; the energy it moves, L x,
// keeps about tol.
#pragma once

#include <cstddef>
#include <functional>
#include <string>
#include <vector>

namespace brdfkit::validate {

struct PresetAxis {
  std::string name;                // the renderer's lookup coordinate ("roughness", "mu", "z", "NoV")
  std::vector<double> coordinate;  // the coordinate of each node, as the renderer looks it up
  std::vector<double> evaluated;   // where the entry is evaluated, in the same coordinate (clamped ends)
};

struct PresetTable {
  std::string name;                   // the array's name in the renderer's source
  std::string definition;             // what an entry is, one line
  std::vector<PresetAxis> axes;       // fastest first
  std::vector<std::string> channels;  // {"E"}, {"s"}, or {"R", "G", "B"}
  // value[node * channels + c], node = i0 + n0 (i1 + n1 i2): the renderer's
  // array order.
  std::vector<double> value, error;
  // Computed from other tables of the preset (kulla_conty's x): its error
  // estimates propagate theirs and are not held to the tolerance, nor in
  // Preset::max_error.
  bool derived = false;
  std::size_t nodes() const {
    std::size_t n = 1;
    for (const PresetAxis& a : axes) n *= a.coordinate.size();
    return n;
  }
};

struct Preset {
  std::string name;
  std::vector<PresetTable> tables;
  double max_error = 0;  // largest error estimate over the entries of the tables not derived
  double seconds = 0;
  std::size_t evals = 0;
};

struct PresetOptions {
  double abs_tolerance = 1e-7;  // on every entry
  // Nodes per axis; 0: the preset's default (filament: 128, as Filament
  // ships, 64 on mobile; kulla_conty: 16). Cycles' sizes are fixed.
  int size = 0;
  std::vector<std::string> tables;  // only these tables of the preset (by array name); empty: all
  // Called from the worker threads with the entries done and the total; an
  // exception it throws stops the build and propagates.
  std::function<void(std::size_t done, std::size_t total)> progress;
};

// "cycles", "filament", "kulla_conty".
std::vector<std::string> PresetNames();
// The nodes per axis of a preset for PresetOptions::size (0: its default).
// Throws ModelError, naming the preset and the accepted range, for a size
// the preset does not take (any for cycles), or for an unknown name.
int PresetSize(const std::string& name, int size);
// Throws ModelError for an unknown name, naming the presets, or for a name
// in options.tables the preset does not have, naming its tables.
Preset BuildPreset(const std::string& name, const PresetOptions& options = {});
// The array names of a preset's tables, in its order.
std::vector<std::string> PresetTableNames(const std::string& name);

// Entries whose error estimate exceeds tolerance, as "table[index] channel:
// error" lines (the worst `shown`), or an empty string.
std::string DescribePresetMisses(const Preset& preset, double tolerance, std::size_t shown = 8);

// Writers (atomic). Header: Cycles' tables as `static const float
// table_...[N] = {...};` in shader.tables' order and layout, Filament's as
// `static const uint16_t DFG_LUT[N * N * 3]` of IEEE half floats (round to
// nearest even) in its texture order; node arrays and a comment on the
// lookup. A path ending in ".inc" gets the bare comma-separated array body,
// as Filament's build includes generated/data/dfg.inc.
void WritePresetHeader(const Preset& preset, const std::string& path);
// CSV: one row per entry: table, index, the axes' coordinates and evaluated
// values, then value and error per channel; every table in one file.
void WritePresetCsv(const Preset& preset, const std::string& path);
// EXR: one part per table (width: the fastest axis; height: the others),
// float32 channels Y or R, G, B, with brdfkit.preset, brdfkit.axes and
// brdfkit.nodes.<axis> attributes.
void WritePresetExr(const Preset& preset, const std::string& path);

// IEEE 754 binary16 bits of v, rounded to nearest even (as Filament's
// half conversion).
unsigned short HalfBits(double v);

}  // namespace brdfkit::validate
