#include "validate/plot.h"

#include <plplot.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <mutex>
#include <random>
#include <stdexcept>

namespace brdfkit::validate {

namespace {

std::mutex& PlplotMutex() {
  static std::mutex m;
  return m;
}

// Series colours (cmap0 slots 1..8), readable on white; slot 9 is the grey
// of secondary series and of missing heat-map cells.
constexpr int kPalette[9][3] = {{31, 119, 180}, {214, 39, 40},  {44, 160, 44},  {148, 103, 189},
                                {255, 127, 14}, {140, 86, 75},  {227, 119, 194}, {23, 190, 207},
                                {185, 185, 185}};

PLINT Slot(int colour, std::size_t position) {
  if (colour == kGrey) return 9;
  return PLINT((colour >= 0 ? std::size_t(colour) : position) % 8) + 1;
}

// The marker of measured points, in the plot and in its legend alike.
constexpr const char* kMarker = "#(228)";

// Legend to the right of the plot area, outside it, so it never covers data.
// Series with an empty label are left out.
void Legend(const std::vector<Series>& series, const std::vector<PLINT>& slots, const std::vector<bool>& markers) {
  std::vector<PLINT> opts, colours, styles, symbol_colours, symbol_numbers, text_colours;
  std::vector<PLFLT> widths, symbol_scales;
  std::vector<const char*> texts, symbols;
  for (std::size_t s = 0; s < series.size(); ++s) {
    if (series[s].label.empty()) continue;
    const bool marker = !markers.empty() && markers[s];
    opts.push_back(marker ? PL_LEGEND_SYMBOL : PL_LEGEND_LINE);
    colours.push_back(slots[s]);
    styles.push_back(1);
    widths.push_back(2.0);
    symbol_colours.push_back(slots[s]);
    symbol_scales.push_back(1.0);
    symbol_numbers.push_back(1);
    symbols.push_back(kMarker);
    texts.push_back(series[s].label.c_str());
    text_colours.push_back(15);
  }
  if (texts.empty()) return;
  PLFLT lw, lh;
  pllegend(&lw, &lh, 0, PL_POSITION_RIGHT | PL_POSITION_OUTSIDE, 0.015, 0.0, 0.06, 0, 15, 1, 0, 0,
           PLINT(texts.size()), opts.data(), 0.6, 0.75, 1.8, 0.0, text_colours.data(), texts.data(), nullptr, nullptr,
           nullptr, nullptr, colours.data(), styles.data(), widths.data(), symbol_colours.data(), symbol_scales.data(),
           symbol_numbers.data(), symbols.data());
}

// The right edge of the plot area (normalised page units, at most
// `preferred`) that leaves room outside it for the legend Legend() draws:
// offset and line sample 0.075 of the plot width, then the longest label at
// text scale 0.6. Browsers draw the SVG's text in their sans-serif font, whose
// characters average about 0.55 em; 0.8 of the character height per
// character is a margin over that (wide labels measure 0.76 in Chromium;
// PLplot's public API has no string metrics).
PLFLT RightEdgeForLegend(const std::vector<Series>& series, PLFLT left, PLFLT preferred) {
  std::size_t longest = 0;
  for (const Series& s : series) longest = std::max(longest, s.label.size());
  if (longest == 0) return preferred;
  PLFLT x0, x1, y0, y1;
  plgspa(&x0, &x1, &y0, &y1);  // the page in millimetres
  PLFLT default_mm, char_mm;
  plgchr(&default_mm, &char_mm);
  const PLFLT text = 0.6 * char_mm * (0.8 * PLFLT(longest) + 3.0) / (x1 - x0);
  const PLFLT right = (0.985 - text + 0.075 * left) / 1.075;
  // A label longer than half the page is cut rather than the plot squeezed away.
  return std::clamp(right, left + 0.45, preferred);
}

// Owns the temporary output file and one PLplot stream; PLplot aborts the
// process when it cannot open its output, so the file is created (and the
// directory checked) here first.
class SvgStream {
 public:
  explicit SvgStream(const std::string& target) : target_(target) {
    namespace fs = std::filesystem;
    if (fs::is_directory(target_)) throw std::runtime_error("cannot write '" + target + "': it is a directory");
    std::random_device rd;
    tmp_ = target_;
    tmp_ += ".tmp-" + std::to_string(rd() % 1000000) + ".svg";
    {
      std::ofstream probe(tmp_);
      if (!probe) throw std::runtime_error("cannot write '" + target + "' (cannot create a file there)");
    }
    plsdev("svg");
    plsfnam(tmp_.c_str());
    plspage(0, 0, 900, 640, 0, 0);
    plscol0(0, 255, 255, 255);  // background
    plscol0(15, 0, 0, 0);       // axes and text
    for (int i = 0; i < 9; ++i) plscol0(i + 1, kPalette[i][0], kPalette[i][1], kPalette[i][2]);
    plinit();
    open_ = true;
  }
  SvgStream(const SvgStream&) = delete;
  SvgStream& operator=(const SvgStream&) = delete;
  ~SvgStream() {
    if (open_) plend();
    if (!committed_) {
      std::error_code ec;
      std::filesystem::remove(tmp_, ec);
    }
  }
  void Commit() {
    plend();
    open_ = false;
    std::error_code ec;
    if (std::filesystem::file_size(tmp_, ec) == 0 || ec)
      throw std::runtime_error("writing '" + target_.string() + "' failed (empty plot output)");
    std::filesystem::rename(tmp_, target_, ec);
    if (ec) throw std::runtime_error("cannot write '" + target_.string() + "': " + ec.message());
    committed_ = true;
  }

 private:
  std::filesystem::path target_, tmp_;
  bool open_ = false, committed_ = false;
};

// Range of finite values with a margin; log10 already applied. A log axis
// covers at least two powers of ten so that it carries two tick labels.
void Range(const std::vector<double>& v, bool log_axis, double& lo, double& hi) {
  lo = std::numeric_limits<double>::infinity();
  hi = -lo;
  for (double x : v) {
    lo = std::min(lo, x);
    hi = std::max(hi, x);
  }
  if (log_axis && std::floor(hi) - std::ceil(lo) < 1) {
    lo = std::floor(lo);
    hi = std::max(std::ceil(hi), lo + 1);
    return;
  }
  // Flat data (a spread within rounding, 1e-9 of the values) would give an
  // axis whose ticks all read the same: half a unit either side instead.
  if (!(hi - lo > 1e-9 * std::max(std::abs(lo), std::abs(hi)))) {
    lo -= 0.5;
    hi += 0.5;
  }
  const double pad = 0.04 * (hi - lo);
  lo -= pad;
  hi += pad;
}

// Viridis (perceptually uniform, readable in grey) through five stops.
void ViridisMap() {
  PLFLT pos[5] = {0, 0.25, 0.5, 0.75, 1};
  PLFLT r[5] = {68 / 255., 59 / 255., 33 / 255., 94 / 255., 253 / 255.};
  PLFLT g[5] = {1 / 255., 82 / 255., 145 / 255., 201 / 255., 231 / 255.};
  PLFLT b[5] = {84 / 255., 139 / 255., 140 / 255., 98 / 255., 37 / 255.};
  plscmap1n(256);
  plscmap1l(1, 5, pos, r, g, b, nullptr);
}

}  // namespace

void LinePlot(const std::string& svg_path, const std::string& title, const std::string& xlabel,
              const std::string& ylabel, const std::vector<Series>& series, bool log_x, bool log_y) {
  // Points as drawn (log10 on log axes), dropping those a log axis cannot show.
  std::vector<std::vector<double>> xs(series.size()), ys(series.size());
  std::vector<double> all_x, all_y;
  for (std::size_t s = 0; s < series.size(); ++s) {
    if (series[s].x.size() != series[s].y.size())
      throw std::invalid_argument("plot '" + svg_path + "': series '" + series[s].label + "' has " +
                                  std::to_string(series[s].x.size()) + " x values but " +
                                  std::to_string(series[s].y.size()) + " y values");
    for (std::size_t i = 0; i < series[s].x.size(); ++i) {
      double x = series[s].x[i], y = series[s].y[i];
      if (!std::isfinite(x) || !std::isfinite(y) || (log_x && !(x > 0)) || (log_y && !(y > 0))) continue;
      if (log_x) x = std::log10(x);
      if (log_y) y = std::log10(y);
      xs[s].push_back(x);
      ys[s].push_back(y);
      all_x.push_back(x);
      all_y.push_back(y);
    }
  }
  if (all_x.empty()) throw std::invalid_argument("plot '" + svg_path + "': no finite points to draw");
  double x0, x1, y0, y1;
  Range(all_x, log_x, x0, x1);
  Range(all_y, log_y, y0, y1);

  std::lock_guard<std::mutex> lock(PlplotMutex());
  SvgStream out(svg_path);
  plcol0(15);
  plschr(0, 0.85);
  pladv(0);
  plvpor(0.1, RightEdgeForLegend(series, 0.1, 0.68), 0.11, 0.91);
  plwind(x0, x1, y0, y1);
  plbox(log_x ? "bcnstgl" : "bcnstg", 0, 0, log_y ? "bcnstvgl" : "bcnstvg", 0, 0);
  pllab(xlabel.c_str(), ylabel.c_str(), title.c_str());
  std::vector<PLINT> slots;
  for (std::size_t s = 0; s < series.size(); ++s) {
    const PLINT colour = Slot(series[s].colour, s);
    slots.push_back(colour);
    plcol0(colour);
    plwidth(2.0);
    if (xs[s].size() > 1) plline(PLINT(xs[s].size()), xs[s].data(), ys[s].data());
    if (!xs[s].empty()) plpoin(PLINT(xs[s].size()), xs[s].data(), ys[s].data(), 17);
  }
  plwidth(1.0);
  Legend(series, slots, {});
  out.Commit();
}

void HeatMap(const std::string& svg_path, const std::string& title, const std::string& xlabel,
             const std::string& ylabel, const std::vector<double>& x_nodes, const std::vector<double>& y_nodes,
             const std::vector<double>& values, const ColourScale& scale) {
  const std::size_t nx = x_nodes.size(), ny = y_nodes.size();
  if (nx < 2 || ny < 2) throw std::invalid_argument("heat map '" + svg_path + "': needs at least 2 x 2 nodes");
  if (values.size() != nx * ny)
    throw std::invalid_argument("heat map '" + svg_path + "': " + std::to_string(values.size()) +
                                " values for a " + std::to_string(nx) + " x " + std::to_string(ny) + " grid");
  for (std::size_t i = 0; i + 1 < nx; ++i)
    if (!(x_nodes[i + 1] > x_nodes[i])) throw std::invalid_argument("heat map '" + svg_path + "': x nodes must increase");
  for (std::size_t i = 0; i + 1 < ny; ++i)
    if (!(y_nodes[i + 1] > y_nodes[i])) throw std::invalid_argument("heat map '" + svg_path + "': y nodes must increase");
  double zmin = std::numeric_limits<double>::infinity(), zmax = -zmin;
  bool missing = false;
  for (double v : values) {
    if (!std::isfinite(v)) {
      missing = true;
      continue;
    }
    zmin = std::min(zmin, v);
    zmax = std::max(zmax, v);
  }
  if (!(zmax >= zmin)) throw std::invalid_argument("heat map '" + svg_path + "': no finite values");
  if (std::isfinite(scale.zmin)) zmin = scale.zmin;
  if (std::isfinite(scale.zmax)) zmax = scale.zmax;
  if (!(zmax > zmin)) {
    zmin -= 0.5;
    zmax += 0.5;
  }

  std::lock_guard<std::mutex> lock(PlplotMutex());
  SvgStream out(svg_path);
  plcol0(15);
  plschr(0, 0.85);
  pladv(0);
  plvpor(0.1, 0.74, 0.11, 0.91);
  plwind(x_nodes.front(), x_nodes.back(), y_nodes.front(), y_nodes.back());
  // Missing cells show this grey: the shades below leave them unfilled.
  plcol0(9);
  PLFLT bx[4] = {x_nodes.front(), x_nodes.back(), x_nodes.back(), x_nodes.front()};
  PLFLT by[4] = {y_nodes.front(), y_nodes.front(), y_nodes.back(), y_nodes.back()};
  plfill(4, bx, by);
  plcol0(15);
  pllab(xlabel.c_str(), ylabel.c_str(), title.c_str());
  const int levels = 33;
  const double span = zmax - zmin;
  PLFLT** z;
  plAlloc2dGrid(&z, PLINT(nx), PLINT(ny));
  for (std::size_t ix = 0; ix < nx; ++ix)
    for (std::size_t iy = 0; iy < ny; ++iy) {
      const double v = values[iy * nx + ix];
      // Saturate just inside the end levels (a value on a level edge may be
      // left unfilled); missing values far below the lowest level.
      z[ix][iy] = std::isfinite(v) ? std::clamp(v, zmin + 1e-6 * span, zmax - 1e-6 * span) : zmin - span;
    }
  std::vector<PLFLT> xg(x_nodes.begin(), x_nodes.end()), yg(y_nodes.begin(), y_nodes.end());
  PLcGrid grid;
  grid.xg = xg.data();
  grid.yg = yg.data();
  grid.zg = nullptr;
  grid.nx = PLINT(nx);
  grid.ny = PLINT(ny);
  std::vector<PLFLT> clevel(levels);
  for (int i = 0; i < levels; ++i) clevel[i] = zmin + span * i / (levels - 1);
  ViridisMap();
  plshades(const_cast<PLFLT_MATRIX>(z), PLINT(nx), PLINT(ny), nullptr, x_nodes.front(), x_nodes.back(),
           y_nodes.front(), y_nodes.back(), clevel.data(), levels, 1.0, 0, 0.0, plfill, 1, pltr1, &grid);
  plFree2dGrid(z, PLINT(nx), PLINT(ny));
  plcol0(15);
  plbox("bcnst", 0, 0, "bcnstv", 0, 0);
  if (missing) plmtex("b", 3.2, 1.0, 1.0, "grey: no data");
  PLFLT cw, ch;
  // log10 values: whole decades as 10^k when the range spans two, otherwise
  // the ticks of the log10 axis labelled with the value itself.
  const std::string axis = !scale.log10_values ? "bcvtm" : span >= 2 ? "bcvtml" : "bcvtmo";
  plslabelfunc(
      [](PLINT, PLFLT value, char* label, PLINT length, PLPointer) {
        std::snprintf(label, std::size_t(length), "%.3g", std::pow(10.0, value));
      },
      nullptr);
  const char* axis_opts[] = {axis.c_str()};
  PLINT label_opts[] = {PL_COLORBAR_LABEL_RIGHT};
  const char* labels[] = {scale.label.c_str()};
  PLINT n_values[] = {levels};
  const PLFLT* values_arr[] = {clevel.data()};
  PLFLT ticks[] = {0.0};
  PLINT sub_ticks[] = {0};
  plcolorbar(&cw, &ch, PL_COLORBAR_SHADE, PL_POSITION_RIGHT | PL_POSITION_OUTSIDE, 0.02, 0.0, 0.035, 1.0, 0, 15, 1,
             0.0, 0.0, 0, 0.0, 1, label_opts, labels, 1, axis_opts, ticks, sub_ticks, n_values, values_arr);
  plslabelfunc(nullptr, nullptr);
  out.Commit();
}

void PolarPlot(const std::string& svg_path, const std::string& title, const std::string& radius_label,
               const std::vector<Series>& series, const std::vector<bool>& markers, const std::vector<int>& colour,
               bool log_radius, int decades) {
  if (markers.size() != series.size() || (!colour.empty() && colour.size() != series.size()))
    throw std::invalid_argument("polar plot '" + svg_path + "': one marker flag (and colour) per series expected");
  double ymax = 0, ymin = INFINITY;
  for (const Series& s : series) {
    if (s.x.size() != s.y.size())
      throw std::invalid_argument("polar plot '" + svg_path + "': series '" + s.label + "' has mismatched sizes");
    for (std::size_t i = 0; i < s.x.size(); ++i)
      if (std::isfinite(s.x[i]) && std::isfinite(s.y[i]) && s.y[i] > 0) {
        ymax = std::max(ymax, s.y[i]);
        ymin = std::min(ymin, s.y[i]);
      }
  }
  if (!(ymax > 0)) throw std::invalid_argument("polar plot '" + svg_path + "': no positive finite radii");
  // decades <= 0: from the power of ten below the smallest value, at most 6 decades.
  if (decades <= 0) decades = std::clamp(int(std::ceil(std::log10(ymax) - std::floor(std::log10(ymin)))), 1, 6);
  const double floor_y = std::pow(10.0, std::ceil(std::log10(ymax)) - decades);
  const auto radius = [&](double y) { return log_radius ? std::max(0.0, std::log10(y / floor_y)) : y; };
  const double rmax = std::max(radius(ymax), log_radius ? double(decades) : 0.0) * 1.05;
  constexpr double kPiLocal = 3.14159265358979323846;

  std::lock_guard<std::mutex> lock(PlplotMutex());
  SvgStream out(svg_path);
  plcol0(15);
  plschr(0, 0.8);
  pladv(0);
  // Equal scales, no box (the grid is drawn below); the left margin holds the -90 label.
  plvpas(0.06, RightEdgeForLegend(series, 0.06, 0.7), 0.04, 0.92, 1.3 / 2);
  plwind(-rmax, rmax, -0.2 * rmax, 1.1 * rmax);
  pllab("", "", title.c_str());
  // Grid: rings (decades on a log radius, quarters otherwise), spokes every 15 degrees.
  pllsty(2);
  const int rings = log_radius ? std::max(1, decades) : 4;
  for (int k = 1; k <= rings; ++k) {
    const double r = log_radius ? double(k) : rmax / 1.05 * k / rings;
    if (log_radius && r > rmax) break;
    plarc(0, 0, r, r, 0, 180, 0, 0);
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.3g", log_radius ? floor_y * std::pow(10.0, k) : r);
    plptex(r, -0.04 * rmax, 1, 0, 0.5, buf);
  }
  for (int deg = -90; deg <= 90; deg += 15) {
    const double a = deg * kPiLocal / 180;
    PLFLT xs[2] = {0, rmax * std::sin(a)}, ys[2] = {0, rmax * std::cos(a)};
    plline(2, xs, ys);
    if (deg % 30 == 0) {
      char buf[16];
      std::snprintf(buf, sizeof buf, "%d", deg);
      plptex(1.05 * xs[1], 1.03 * ys[1] + 0.01 * rmax, 1, 0, 0.5, buf);
    }
  }
  pllsty(1);
  plptex(0, -0.1 * rmax, 1, 0, 0.5,
         (radius_label + (log_radius ? ", log radius" : "") + "; angle from the normal in degrees").c_str());
  std::vector<PLINT> slots;
  for (std::size_t s = 0; s < series.size(); ++s) {
    std::vector<double> x, y;
    for (std::size_t i = 0; i < series[s].x.size(); ++i) {
      const double a = series[s].x[i], v = series[s].y[i];
      if (!std::isfinite(a) || !std::isfinite(v) || v <= 0) continue;
      const double r = radius(v);
      x.push_back(r * std::sin(a));
      y.push_back(r * std::cos(a));
    }
    const PLINT c = Slot(colour.empty() ? series[s].colour : colour[s], s);
    slots.push_back(c);
    plcol0(c);
    plwidth(2.0);
    if (markers[s]) {
      if (!x.empty()) plstring(PLINT(x.size()), x.data(), y.data(), kMarker);
    } else if (x.size() > 1) {
      plline(PLINT(x.size()), x.data(), y.data());
    }
  }
  plwidth(1.0);
  Legend(series, slots, markers);
  out.Commit();
}

const char* PaletteCss(int index) {
  static const char* kCss[9] = {"#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e",
                                "#8c564b", "#e377c2", "#17becf", "#b9b9b9"};
  return kCss[index == kGrey ? 8 : (index % 8 + 8) % 8];
}

}  // namespace brdfkit::validate
