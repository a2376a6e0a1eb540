// SVG plots through PLplot (svg driver): line plots with optional log axes
// and heat maps on a (possibly non-uniform) grid. Files are written under a
// temporary name beside the target and renamed when complete. PLplot keeps
// global state, so calls are serialised by a mutex; they are safe to make
// from several threads.
#pragma once

#include <cmath>
#include <string>
#include <vector>

namespace brdfkit::validate {

// Series colour: a palette index (0..7), kGrey, or -1 for one colour per
// series in order. A series with an empty label has no legend entry.
constexpr int kGrey = 8;
struct Series {
  std::string label;
  std::vector<double> x, y;
  int colour = -1;
};

// The palette as CSS colours (the explorer page uses the same ones).
const char* PaletteCss(int index);

// Log axes drop points that are not strictly positive. Throws
// std::runtime_error naming the file when it cannot be written, and
// std::invalid_argument for mismatched x/y sizes or no finite points at all.
void LinePlot(const std::string& svg_path, const std::string& title, const std::string& xlabel,
              const std::string& ylabel, const std::vector<Series>& series, bool log_x, bool log_y);

// Colour scale of a heat map. Values outside [zmin, zmax] are drawn in the
// end colours (saturated); NaN (missing) cells in grey. NaN bounds: the
// range of the finite values. With log10_values the values are log10 of
// the quantity and the colour bar is labelled in powers of ten.
struct ColourScale {
  std::string label;  // of the colour bar, with units
  double zmin = NAN, zmax = NAN;
  bool log10_values = false;
};

// values are row-major: values[iy * x_nodes.size() + ix]; nodes must be
// strictly increasing. Cells are shaded by value with a colour bar.
void HeatMap(const std::string& svg_path, const std::string& title, const std::string& xlabel,
             const std::string& ylabel, const std::vector<double>& x_nodes, const std::vector<double>& y_nodes,
             const std::vector<double>& values, const ColourScale& scale = {});

// Polar plot of BRDF slices: each series gives signed angles from the
// normal (radians, in [-pi/2, pi/2], x) and radii (y, >= 0); the normal
// points up, angle a at (r sin a, r cos a). Series with markers[s] = true
// are drawn as points (measurements), the others as lines (models);
// colour[s] picks the palette entry (empty: one colour per series). With
// log_radius the radius is log10(y / floor), floor = max(y) / 10^decades,
// and values below the floor sit at the centre.
void PolarPlot(const std::string& svg_path, const std::string& title, const std::string& radius_label,
               const std::vector<Series>& series, const std::vector<bool>& markers,
               const std::vector<int>& colour = {}, bool log_radius = false, int decades = 3);

}  // namespace brdfkit::validate
