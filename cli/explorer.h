// The BRDF explorer: values of one or more materials precomputed by brdfkit
// on fixed angle grids, embedded (base64 float32) in a self-contained HTML
// section with the page's script (cli/explorer/explorer.js), which only
// draws and looks values up: it evaluates no model.
//
// Grids (degrees): theta_i 0..88 step 2; phi_i 0..180 step 30 for a material
// whose values change with the azimuth of incidence, else phi_i = 0 only.
// Slices through the normal: "in-plane" in the plane of incidence (signed
// angle of wo, positive towards the light), "out-of-plane" in the plane
// through the normal perpendicular to it (positive towards phi_i + 90).
// Lobe: theta_o 0..90 step 6 x phi_o 0..360 step 12. theta_h x theta_d
// image at phi_d = 90 deg on the MERL bin centres. Directional albedo E(wo)
// at wo = (theta_i, phi_i).
#pragma once

#include <string>
#include <vector>

#include "cli/common.h"

namespace brdfkit::cli {

struct ExplorerMaterial {
  std::string label;
  std::string description;
  LoadedModel model;
};

// MATERIAL text as `brdfkit view` takes it: MODEL or MODEL:PARAMS, where
// MODEL is what --model accepts (ggx, lambert+ggx, merl:FILE, fit:FILE.json)
// and PARAMS what --params accepts. The parameters start after the first
// ':' that is followed by `name=`.
ExplorerMaterial ParseMaterialArg(const std::string& text);

// <section> with the data, the styles and the script; one per page.
std::string ExplorerSection(const std::vector<ExplorerMaterial>& materials);

// A complete page around the section.
std::string ExplorerPage(const std::string& title, const std::vector<ExplorerMaterial>& materials);

std::string Base64(const std::string& bytes);
std::string HtmlEscape(const std::string& text);

}  // namespace brdfkit::cli
