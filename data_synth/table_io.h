// Tabulated BRDF samples as CSV: the interchange format of brdfkit's
// synthesiser (writer) and fitter (reader).
//
// Header: theta_i,phi_i,theta_o,phi_o,f_r,f_g,f_b[,sigma_r,sigma_g,sigma_b]
// Angles in radians (spherical angles of wi and wo in the local frame, z the
// normal), f in 1/sr without the cosine, sigma the standard deviation of f.
// A single `f` column (and optionally `sigma`) is read as grey. Columns may
// come in any order; unknown columns are an error so a typo is not ignored.
// A row with an empty or NaN field is a missing sample: it is counted in
// `missing` and skipped.
#pragma once

#include <Eigen/Core>

#include <cstddef>
#include <string>
#include <vector>

namespace brdfkit::synth {

struct BrdfSample {
  double theta_i, phi_i, theta_o, phi_o;
  Eigen::Array3d f, sigma;
};

struct BrdfTable {
  std::vector<BrdfSample> rows;
  bool has_sigma = false;
  std::size_t missing = 0;
};

// Throws std::runtime_error naming the file (and line) on any malformed input.
BrdfTable ReadTableCsv(const std::string& path);

// Writes atomically (no partial file on failure), values with %.17g so they
// read back bit for bit. Sigma columns are written when table.has_sigma.
void WriteTableCsv(const std::string& path, const BrdfTable& table);

}  // namespace brdfkit::synth
