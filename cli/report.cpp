// report.html: one self-contained page (no network): verdicts, tables,
// figures embedded as SVG data URIs, and the wall time of every task. A
// script counts the figures that decoded and rendered and writes the count
// into <body data-figures-rendered="N/M">, which the tests read back from a
// headless browser. Below the tasks, the explorer shows the measured
// materials and their fits.
#include <cmath>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "brdf/atomic_file.h"
#include "cli/explorer.h"
#include "cli/run.h"

namespace brdfkit::cli {

namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;

std::string Esc(const std::string& s) { return HtmlEscape(s); }

std::string Num(const json& v, const char* fmt = "%.6g") {
  if (!v.is_number()) return "&ndash;";
  char buf[64];
  std::snprintf(buf, sizeof buf, fmt, v.get<double>());
  return buf;
}

std::string Seconds(double s) {
  char buf[32];
  std::snprintf(buf, sizeof buf, s < 10 ? "%.2f s" : "%.1f s", s);
  return buf;
}

// "name=value,..." (colour values r:g:b) as a small two-column table.
std::string ParamsTable(const std::string& text) {
  std::string rows;
  std::stringstream in(text);
  std::string item;
  while (std::getline(in, item, ',')) {
    const auto eq = item.find('=');
    std::string value = eq == std::string::npos ? "" : item.substr(eq + 1);
    for (char& c : value) c = c == ':' ? ' ' : c;
    rows += "<tr><td><code>" + Esc(item.substr(0, eq)) + "</code></td><td>" + Esc(value) + "</td></tr>";
  }
  return rows.empty() ? "" : "<table class=\"params\">" + rows + "</table>";
}

// Markdown pipe tables (the convergence summary) as HTML.
std::string MarkdownTable(const std::string& md) {
  std::istringstream in(md);
  std::string line, html, text;
  bool in_table = false, header = true;
  while (std::getline(in, line)) {
    if (line.rfind("|", 0) == 0) {
      if (line.find("---") != std::string::npos) continue;
      if (!in_table) html += "<table>";
      in_table = true;
      html += "<tr>";
      std::stringstream cells(line.substr(1));
      std::string cell;
      while (std::getline(cells, cell, '|')) {
        const auto a = cell.find_first_not_of(' '), b = cell.find_last_not_of(' ');
        const std::string c = a == std::string::npos ? "" : cell.substr(a, b - a + 1);
        html += header ? "<th>" + Esc(c) + "</th>" : "<td>" + Esc(c) + "</td>";
      }
      html += "</tr>";
      header = false;
    } else if (!line.empty() && line[0] != '#') {
      html += "<p>" + Esc(line) + "</p>";
    }
  }
  if (in_table) html += "</table>";
  return html;
}

std::string FigureHtml(const Figure& f, const std::string& out_dir) {
  std::ifstream in(fs::path(out_dir) / f.file, std::ios::binary);
  std::ostringstream ss;
  ss << in.rdbuf();
  return "<figure><img class=\"plot\" alt=\"" + Esc(f.title) + "\" src=\"data:image/svg+xml;base64," + Base64(ss.str()) +
         "\"><figcaption><b>" + Esc(f.title) + ".</b> " + Esc(f.caption) + " <a href=\"" + Esc(f.file) +
         "\">" + Esc(f.file) + "</a></figcaption></figure>\n";
}

std::string CheckHtml(const json& r) {
  std::string h = "<table><tr><th>material</th><th>verdict</th><th>reciprocity error</th><th>albedo max (at mu)</th>"
                  "<th>min f_r</th><th>non-finite</th><th>chi&sup2; p</th><th>failed</th></tr>";
  for (const json& m : r.at("materials")) {
    const std::string verdict = m.value("verdict", m.at("plausible").get<bool>() ? "plausible" : "implausible");
    const char* css = verdict == "plausible" ? "ok" : (verdict == "implausible" ? "bad" : "undecided");
    std::string reasons;
    for (const json& s : m.at("reasons")) reasons += "<li>" + Esc(s.get<std::string>()) + "</li>";
    for (const json& s : m.value("inconclusive", json::array()))
      reasons += "<li>inconclusive: " + Esc(s.get<std::string>()) + "</li>";
    h += "<tr><td><b>" + Esc(m.at("material").get<std::string>()) + "</b><br><small><code>" +
         Esc(m.value("model", "")) + "</code></small>" + ParamsTable(m.value("params", "")) + "</td><td class=\"" +
         css + "\">" + verdict + "</td><td>" + Num(m.at("reciprocity_max_rel_error"), "%.3g") +
         "</td><td>" + Num(m.at("albedo_max"), "%.6f") + " (" + Num(m.at("albedo_max_at_mu"), "%.3g") + ")</td><td>" +
         Num(m.at("min_value"), "%.3g") + "</td><td>" + std::to_string(m.at("nonfinite_count").get<long long>()) +
         "</td><td>" + Num(m.at("chi2_p_value"), "%.3g") + "</td><td><ul>" + reasons + "</ul></td></tr>";
  }
  return "<div class=\"wide\">" + h + "</table></div>";
}

std::string FitHtml(const json& r) {
  std::string h = "<p>model <code>" + Esc(r.at("model").get<std::string>()) + "</code>, metric " +
                  Esc(r.at("metric").get<std::string>()) + ", " + std::to_string(r.at("samples").get<long long>()) +
                  " samples, " + std::to_string(r.at("iterations").get<int>()) + " iterations, rmse " +
                  Num(r.at("rmse")) + ", " + (r.at("converged").get<bool>() ? "converged" : "<b>not converged</b>") +
                  ". Uncertainty: " + Esc(r.at("uncertainty").get<std::string>()) + ".</p>";
  h += "<table><tr><th>parameter</th><th>value</th><th>standard deviation</th></tr>";
  const json& p = r.at("params");
  const json& s = r.at("stddev");
  for (auto it = p.begin(); it != p.end(); ++it) {
    std::string v, d;
    if (it->is_array()) {
      for (std::size_t c = 0; c < it->size(); ++c) {
        v += (c ? ", " : "") + Num((*it)[c], "%.6g");
        d += (c ? ", " : "") + Num(s.at(it.key())[c], "%.2g");
      }
    } else {
      v = Num(*it, "%.6g");
      d = Num(s.at(it.key()), "%.2g");
    }
    h += "<tr><td>" + Esc(it.key()) + "</td><td>" + v + "</td><td>" + d + "</td></tr>";
  }
  h += "</table><p><small>Standard deviations are statistical given the model: how well the data determine this "
       "model's parameters, not how far the model is from the material. Reduced chi-square: " +
       (r.contains("chi2_reduced") && r.at("chi2_reduced").is_number() ? Num(r.at("chi2_reduced"), "%.4g")
                                                                         : std::string("none (the data carry no sigma)")) +
       ".</small></p>";
  if (r.contains("relative_error")) {
    h += "<table><tr><th>relative error |f_fit - f_data| / f_data</th><th>median</th><th>95th percentile</th>"
         "<th>max</th><th>values</th></tr>";
    const auto row = [&](const std::string& label, const json& e) {
      h += "<tr><td>" + label + "</td><td>" + Num(e.at("median"), "%.3g") + "</td><td>" + Num(e.at("p95"), "%.3g") +
           "</td><td>" + Num(e.at("max"), "%.3g") + "</td><td>" + std::to_string(e.at("count").get<long long>()) +
           "</td></tr>";
    };
    row("all samples", r.at("relative_error"));
    for (const json& b : r.value("relative_error_bands", json::array()))
      row("theta_h " + Num(b.at("theta_h_deg")[0], "%g") + "&ndash;" + Num(b.at("theta_h_deg")[1], "%g") + "&deg;", b);
    h += "</table>";
  }
  for (const json& w : r.value("warnings", json::array()))
    h += "<p class=\"bad\">Warning: " + Esc(w.get<std::string>()) + "</p>";
  return h;
}

std::string SynthHtml(const json& r) {
  if (r.value("camera", false))
    return "<p>Camera measurement of <b>" + Esc(r.at("material").get<std::string>()) + "</b> (" +
           Esc(r.at("description").get<std::string>()) + "): " + std::to_string(r.at("images").get<long long>()) +
           " raw image(s), reduced to " + std::to_string(r.at("samples").get<long long>()) + " BRDF samples.</p>";
  return "<p>Material <b>" + Esc(r.at("material").get<std::string>()) + "</b> (" +
         Esc(r.at("description").get<std::string>()) + ") through instrument <b>" +
         Esc(r.at("instrument").get<std::string>()) + "</b>: " + std::to_string(r.at("measured").get<long long>()) +
         " pairs measured, " + std::to_string(r.at("not_measured").get<long long>()) + " not measurable, " +
         std::to_string(r.at("saturated").get<long long>()) + " saturated; aperture quadrature order " +
         std::to_string(r.at("aperture_order").get<int>()) + " (estimated relative error " +
         Num(r.at("quadrature_error"), "%.2g") + ", " +
         std::to_string(r.value("pairs_above_tolerance", 0LL)) + " pairs above the tolerance)" +
         (r.at("noisy").get<bool>() ? ", with sensor noise" : "") + ".</p>";
}

std::string AlbedoHtml(const json& r) {
  if (r.contains("preset")) {
    std::string h = "<p>" + Esc(r.at("preset").get<std::string>()) + "'s table set, largest quadrature error estimate " +
                    Num(r.at("max_error"), "%.2g") + ":</p>\n<ul>\n";
    for (const json& t : r.at("tables"))
      h += "<li><code>" + Esc(t.at("name").get<std::string>()) + "</code> (" +
           std::to_string(t.at("entries").get<long long>()) + " entries): " +
           Esc(t.at("definition").get<std::string>()) + "</li>\n";
    return h + "</ul>";
  }
  std::string axes;
  for (const json& a : r.at("axes"))
    axes += (axes.empty() ? "" : ", ") + Esc(a.at("name").get<std::string>()) + " (" +
            std::to_string(a.at("nodes").size()) + " nodes)";
  const std::string of = r.contains("material") ? "material '" + Esc(r.at("material").get<std::string>()) + "' (" +
                                                       Esc(r.at("model").get<std::string>()) + ")"
                                                 : Esc(r.at("model").get<std::string>());
  return "<p>" + of + ": " + std::to_string(r.at("entries").get<long long>()) + " entries over mu (" +
         std::to_string(r.at("mu").size()) + " nodes)" + (axes.empty() ? "" : " and " + axes) +
         "; largest quadrature error estimate " + Num(r.at("max_error"), "%.2g") + ", grazing-limit error " +
         Num(r.at("limit_error"), "%.2g") + ".</p>";
}

}  // namespace

void WriteReport(const std::string& path, const Scene& scene, const std::vector<TaskOutcome>& outcomes,
                 const std::vector<PlanItem>& plan, const std::string& out_dir, double seconds) {
  std::string h;
  h += "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>brdfkit report: " +
       Esc(scene.title.empty() ? scene.origin : scene.title) + "</title>\n<style>\n"
       "body{font-family:sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;color:#222}\n"
       "table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #ccc;padding:4px 8px;text-align:left;"
       "vertical-align:top;overflow-wrap:anywhere}th{background:#f3f3f3}td ul{min-width:14em}\n"
       "div.wide{overflow-x:auto}table.params{margin:4px 0 0;font-size:85%}table.params td{padding:1px 5px}\n.ok{color:#1a7f37;font-weight:bold}.bad{color:#c62828;"
       "font-weight:bold}.undecided{color:#9a6700;font-weight:bold}\nfigure{margin:1em 0}img.plot{max-width:100%;border:1px solid #ddd}figcaption{font-size:"
       "90%;color:#444}\nul{margin:0;padding-left:1.2em}code{background:#f3f3f3;padding:0 3px}\n</style></head>\n"
       "<body data-figures-rendered=\"pending\">\n";
  h += "<h1>brdfkit report" + (scene.title.empty() ? std::string() : ": " + Esc(scene.title)) + "</h1>\n";
  h += "<p>Scene <code>" + Esc(scene.origin) + "</code>, brdfkit " BRDFKIT_VERSION ", total wall time " +
       Seconds(seconds) + ". Figures: <span id=\"figure-status\">checking</span>.</p>\n";
  h += "<h2>Tasks</h2>\n<table><tr><th>task</th><th>type</th><th>status</th><th>why</th><th>wall time</th></tr>\n";
  for (const PlanItem& p : plan) {
    const TaskOutcome* o = nullptr;
    for (const TaskOutcome& x : outcomes)
      if (x.name == p.task->name) o = &x;
    std::string status = p.action == PlanItem::Action::kSkip ? "skipped" : o ? o->status : "not run";
    std::string time = o ? Seconds(o->seconds) + (o->status == "cached" ? " (earlier run)" : "") : "&ndash;";
    h += "<tr><td><a href=\"#task-" + Esc(p.task->name) + "\">" + Esc(p.task->name) + "</a></td><td>" +
         p.task->TypeName() + "</td><td>" + status + "</td><td>" + Esc(p.why) + "</td><td>" + time +
         "</td></tr>\n";
  }
  h += "</table>\n";
  for (const TaskOutcome& o : outcomes) {
    h += "<h2 id=\"task-" + Esc(o.name) + "\">" + Esc(o.name) + " <small>(" + Esc(o.type) + ", " + Seconds(o.seconds) +
         (o.status == "cached" ? ", from the cache" : "") + ")</small></h2>\n";
    if (o.type == "check") h += CheckHtml(o.result);
    else if (o.type == "albedo") h += AlbedoHtml(o.result);
    else if (o.type == "synth") h += SynthHtml(o.result);
    else if (o.type == "fit") h += FitHtml(o.result);
    else if (o.type == "convergence") h += MarkdownTable(o.result.at("summary_markdown").get<std::string>());
    for (const Figure& f : o.figures) h += FigureHtml(f, out_dir);
    std::string files;
    for (const std::string& f : o.files) files += (files.empty() ? "" : ", ") + ("<a href=\"" + Esc(f) + "\">" + Esc(f) + "</a>");
    h += "<p><small>Files: " + files + "</small></p>\n";
  }
  std::vector<ExplorerMaterial> explore;
  for (const auto& [name, m] : scene.materials) {
    bool shown = m.kind == MaterialSpec::Kind::kFit;
    for (const TaskOutcome& o : outcomes)
      if (o.type == "synth" && o.result.value("material", "") == name) shown = true;
    if (!shown || m.kind == MaterialSpec::Kind::kTable) continue;
    if (m.kind == MaterialSpec::Kind::kFit && !fs::exists(fs::path(out_dir) / m.fit_task / "fit.json")) continue;
    LoadedModel lm = MaterialModel(m, RunContext{scene, out_dir, true});
    explore.push_back({name, lm.model.Spec() + " (" + FormatParams(lm.model.Info(), lm.params) + ")", lm});
  }
  if (!explore.empty())
    h += "<h2 id=\"explorer\">Explorer: the measured materials and their fits</h2>\n"
         "<p>Values computed by brdfkit on fixed angle grids (see <code>brdfkit view</code>); move the sliders, "
         "hover for values.</p>\n" + ExplorerSection(explore);
  h += "<script>\n"
       "window.addEventListener('load', function () {\n"
       "  var imgs = document.querySelectorAll('img.plot'), ok = 0;\n"
       "  for (var i = 0; i < imgs.length; ++i)\n"
       "    if (imgs[i].complete && imgs[i].naturalWidth > 0 && imgs[i].getBoundingClientRect().width > 0) ++ok;\n"
       "  var text = ok + '/' + imgs.length;\n"
       "  document.body.setAttribute('data-figures-rendered', text);\n"
       "  document.getElementById('figure-status').textContent = text + ' rendered';\n"
       "});\n</script>\n</body></html>\n";
  WriteFileAtomic(path, h);
}

}  // namespace brdfkit::cli
