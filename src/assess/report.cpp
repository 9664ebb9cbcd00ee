// The session report (docs/assessment.md): a run's folder read back (metrics.json, series.csv,
// frames.csv and frames/), checked at this boundary, and rendered through a Mustache template
// into one HTML file with everything inlined: the plotting library (dygraphs), the data, the key
// frames (PNG as data URIs), the timeline and the tip's path over an angiogram (SVG).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <kainjow/mustache.hpp>
#include <map>
#include <sstream>

#include "json_fields.h"
#include "vcsim/assess.h"
#include "vcsim/render.h"

namespace vcsim {

namespace fs = std::filesystem;
using Json = nlohmann::json;
using internal::cat;
namespace mu = kainjow::mustache;

namespace {

std::string slurp(const fs::path& p, const std::string& what) {
  std::ifstream f(p, std::ios::binary);
  if (!f) throw InputError(p.string(), "file", "expected " + what);
  std::stringstream ss;
  ss << f.rdbuf();
  return ss.str();
}

std::string base64(const std::string& in) {
  static const char* k = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  out.reserve((in.size() + 2) / 3 * 4);
  std::size_t i = 0;
  for (; i + 2 < in.size(); i += 3) {
    const unsigned v = (static_cast<unsigned char>(in[i]) << 16) |
                       (static_cast<unsigned char>(in[i + 1]) << 8) |
                       static_cast<unsigned char>(in[i + 2]);
    for (int s = 18; s >= 0; s -= 6) out += k[(v >> s) & 63];
  }
  if (i < in.size()) {
    unsigned v = static_cast<unsigned char>(in[i]) << 16;
    if (i + 1 < in.size()) v |= static_cast<unsigned char>(in[i + 1]) << 8;
    out += k[(v >> 18) & 63];
    out += k[(v >> 12) & 63];
    out += i + 1 < in.size() ? k[(v >> 6) & 63] : '=';
    out += '=';
  }
  return out;
}

// JSON inside a <script>: "</" would end the element.
std::string script_json(const Json& j) {
  std::string s = j.dump();
  std::string out;
  out.reserve(s.size());
  for (std::size_t i = 0; i < s.size(); ++i) {
    if (s[i] == '<' && i + 1 < s.size() && s[i + 1] == '/') {
      out += "<\\/";
      ++i;
    } else {
      out += s[i];
    }
  }
  return out;
}

std::string xml_escape(const std::string& s) {
  std::string o;
  for (char c : s) {
    switch (c) {
      case '&':
        o += "&amp;";
        break;
      case '<':
        o += "&lt;";
        break;
      case '>':
        o += "&gt;";
        break;
      case '"':
        o += "&quot;";
        break;
      default:
        o += c;
    }
  }
  return o;
}

std::string fmt(double v, int decimals) {
  char buf[48];
  std::snprintf(buf, sizeof buf, "%.*f", decimals, v);
  return buf;
}

// ---------------------------------------------------------------------------------------------
// Reading a run's folder

struct Series {
  std::vector<std::string> columns;
  std::vector<std::vector<double>> rows;  // NaN: empty cell
  int column(const std::string& name) const {
    for (std::size_t c = 0; c < columns.size(); ++c)
      if (columns[c] == name) return static_cast<int>(c);
    return -1;
  }
};

Series read_csv(const fs::path& file, const std::string& what) {
  std::ifstream in(file);
  if (!in) throw InputError(file.string(), "file", "expected " + what);
  Series s;
  std::string line;
  if (!std::getline(in, line) || line.empty())
    throw InputError(file.string(), "line 1", "expected a header of column names");
  {
    std::stringstream ss(line);
    std::string c;
    while (std::getline(ss, c, ',')) s.columns.push_back(c);
  }
  int n = 1;
  while (std::getline(in, line)) {
    ++n;
    if (line.empty()) continue;
    std::vector<double> row;
    std::size_t start = 0;
    while (true) {
      const std::size_t comma = line.find(',', start);
      const std::string cell =
          line.substr(start, comma == std::string::npos ? comma : comma - start);
      if (cell.empty()) {
        row.push_back(std::nan(""));
      } else {
        char* end = nullptr;
        const double v = std::strtod(cell.c_str(), &end);
        if (end != cell.c_str() + cell.size() || !std::isfinite(v))
          throw InputError(file.string(), cat("line ", std::to_string(n)),
                           cat("expected numbers, got '", cell, "'"));
        row.push_back(v);
      }
      if (comma == std::string::npos) break;
      start = comma + 1;
    }
    if (row.size() != s.columns.size())
      throw InputError(file.string(), cat("line ", std::to_string(n)),
                       cat("expected ", std::to_string(s.columns.size()), " values, got ",
                           std::to_string(row.size())));
    s.rows.push_back(std::move(row));
  }
  return s;
}

struct Run {
  fs::path dir;
  Json metrics;
  const Json* a = nullptr;  // metrics["assessment"]
};

Run load_run(const fs::path& dir) {
  if (!fs::is_directory(dir))
    throw InputError(dir.string(), "RUN_DIR", "expected the folder of a run (vcsim run --out)");
  Run r;
  r.dir = dir;
  const fs::path file = dir / "metrics.json";
  if (!fs::exists(file))
    throw InputError(dir.string(), "metrics.json",
                     "expected a run folder holding metrics.json (written by vcsim run)");
  const std::string src = file.string();
  r.metrics = internal::parse_json_text(slurp(file, "a readable metrics.json"), src);
  const Json& m = r.metrics;
  if (!m.is_object()) throw InputError(src, "json", "expected an object");
  if (!m.contains("format") || m["format"] != "vcsim-metrics")
    throw InputError(src, "format",
                     "expected \"vcsim-metrics\" (a metrics file of vcsim version 2 or later)");
  if (!m.contains("version") || !m["version"].is_number_integer() ||
      m["version"].get<long long>() != kMetricsVersion)
    throw InputError(
        src, "version",
        cat("expected ", std::to_string(kMetricsVersion), ", got ",
            m.contains("version") ? internal::describe_json(m["version"]) : std::string("none"),
            " (run it again with this vcsim)"));
  if (!m.contains("assessment") || !m["assessment"].is_object())
    throw InputError(src, "assessment", "expected the assessment section (written by vcsim run)");
  r.a = &m["assessment"];
  const Json& a = *r.a;
  // What the report reads, each of the type it reads it as; then only num() and str() look
  // inside, and they take a missing or mistyped field as absent.
  for (const char* key : {"summary", "settings", "beam", "dose", "contrast", "view", "treatment"})
    if (!a.contains(key) || !a[key].is_object())
      throw InputError(src, cat("assessment.", key), "expected an object (written by vcsim run)");
  for (const char* key : {"instruments", "events", "intervals", "phases", "lesions"}) {
    if (!a.contains(key) || !a[key].is_array())
      throw InputError(src, cat("assessment.", key), "expected an array (written by vcsim run)");
    for (std::size_t i = 0; i < a[key].size(); ++i)
      if (!a[key][i].is_object())
        throw InputError(src, internal::index_path(cat("assessment.", key), i),
                         "expected an object");
  }
  const Json& c = a["contrast"];
  if (!c.contains("injections") || !c["injections"].is_array())
    throw InputError(src, "assessment.contrast.injections", "expected an array");
  for (std::size_t i = 0; i < c["injections"].size(); ++i)
    if (!c["injections"][i].is_object())
      throw InputError(src, internal::index_path("assessment.contrast.injections", i),
                       "expected an object");
  for (auto& [k, v] : (*r.a)["summary"].items())
    if (!v.is_number() && !v.is_null())
      throw InputError(src, cat("assessment.summary.", k), "expected a number or null");
  return r;
}

double num(const Json& j, const char* key, double fallback = std::nan("")) {
  const auto it = j.find(key);
  return it != j.end() && it->is_number() ? it->get<double>() : fallback;
}

std::string str(const Json& j, const char* key) {
  const auto it = j.find(key);
  return it != j.end() && it->is_string() ? it->get<std::string>() : std::string();
}

// ---------------------------------------------------------------------------------------------
// The metrics against their references (data/report/reference.json)

struct Reference {
  std::string key, label, unit, source;
  double low = std::nan(""), high = std::nan("");
  int decimals = 1;
};

std::vector<Reference> load_references() {
  const char* env = std::getenv("VCSIM_REPORT_REFERENCE");
  const fs::path file = env && *env ? fs::path(env) : fs::path(VCSIM_DEFAULT_REFERENCE_FILE);
  const std::string src = file.string();
  const Json j = internal::parse_json_text(slurp(file, "the report's reference ranges"), src);
  internal::JsonFields f(j, src, "");
  f.keys({"format", "version", "comment", "metrics"});
  if (f.string("format") != "vcsim-report-reference")
    throw InputError(src, "format", "expected \"vcsim-report-reference\"");
  if (f.number("version") != 1) throw InputError(src, "version", "expected 1");
  const Json& list = f.require("metrics");
  if (!list.is_array()) throw InputError(src, "metrics", "expected an array");
  std::vector<Reference> out;
  for (std::size_t i = 0; i < list.size(); ++i) {
    internal::JsonFields e(list[i], src, internal::index_path("metrics", i));
    e.keys({"key", "label", "unit", "low", "high", "source", "decimals"});
    Reference r;
    r.key = e.string("key");
    r.label = e.string("label");
    r.unit = e.has("unit") ? e.string("unit") : "";
    if (e.has("low")) r.low = e.number("low");
    if (e.has("high")) r.high = e.number("high");
    r.source = e.has("source") ? e.string("source") : "";
    r.decimals = static_cast<int>(e.number_or("decimals", 1));
    e.finish();
    out.push_back(r);
  }
  f.finish();
  return out;
}

std::string range_text(const Reference& r) {
  const bool lo = std::isfinite(r.low), hi = std::isfinite(r.high);
  if (lo && hi) return fmt(r.low, r.decimals) + " - " + fmt(r.high, r.decimals);
  if (hi) return "<= " + fmt(r.high, r.decimals);
  if (lo) return ">= " + fmt(r.low, r.decimals);
  return "";
}

// "ok" inside the reference range, "out" outside, "none" without one (or without a value).
std::string status_of(const Json& v, const Reference& r) {
  if (!v.is_number() || (!std::isfinite(r.low) && !std::isfinite(r.high))) return "none";
  const double x = v.get<double>();
  const bool ok = (!std::isfinite(r.low) || x >= r.low - 1e-12) &&
                  (!std::isfinite(r.high) || x <= r.high + 1e-12);
  return ok ? "ok" : "out";
}

// ---------------------------------------------------------------------------------------------
// Pictures

struct FramePick {
  std::string caption;
  double time = 0.0;
};

// The frame nearest to time t (frames.csv), or -1.
int frame_at(const Series& frames, double t) {
  int best = -1;
  double d = 1e300;
  for (std::size_t k = 0; k < frames.rows.size(); ++k) {
    const double dk = std::abs(frames.rows[k][1] - t);
    if (dk < d) {
      d = dk;
      best = static_cast<int>(k);
    }
  }
  return best;
}

fs::path frame_file(const fs::path& dir, int k) {
  char name[32];
  std::snprintf(name, sizeof name, "frame_%05d.png", k);
  return dir / "frames" / name;
}

const char* kColours[] = {"#e6550d", "#31a354", "#3182bd", "#d62728", "#9467bd", "#8c564b"};

// The timeline: phases, each instrument inside the patient, the beam, injections, inflations,
// and the events as numbered marks.
std::string timeline_svg(const Json& a, double end, std::vector<std::string>& rows_out) {
  std::vector<std::string> rows;
  if (!a["phases"].empty()) rows.push_back("phase");
  for (const Json& i : a["instruments"]) rows.push_back(str(i, "name"));
  for (const Json& iv : a["intervals"]) {
    const std::string r = str(iv, "row");
    if (std::find(rows.begin(), rows.end(), r) == rows.end()) rows.push_back(r);
  }
  rows.push_back("events");
  const double W = 1000, left = 170, top = 8, rh = 22;
  const double H = top + rh * static_cast<double>(rows.size()) + 24;
  const double span = end > 0 ? end : 1.0;
  auto X = [&](double t) { return left + (W - left - 10) * std::clamp(t / span, 0.0, 1.0); };
  auto Y = [&](const std::string& row) {
    const auto it = std::find(rows.begin(), rows.end(), row);
    return top + rh * static_cast<double>(it - rows.begin());
  };
  std::ostringstream s;
  s << "<svg xmlns='http://www.w3.org/2000/svg' id='timeline' viewBox='0 0 " << W << ' ' << H
    << "' width='100%'>";
  for (std::size_t r = 0; r < rows.size(); ++r) {
    const double y = top + rh * static_cast<double>(r);
    s << "<rect x='0' y='" << y << "' width='" << W << "' height='" << rh << "' fill='"
      << (r % 2 ? "#f7f7f7" : "#ffffff") << "'/>";
    s << "<text x='6' y='" << y + 15 << "' font-size='12'>" << xml_escape(rows[r]) << "</text>";
  }
  int k = 0;
  for (const Json& ph : a["phases"]) {
    const double x0 = X(num(ph, "start_s", 0)), x1 = X(num(ph, "end_s", end));
    s << "<rect x='" << x0 << "' y='" << Y("phase") + 3 << "' width='" << std::max(1.0, x1 - x0)
      << "' height='" << rh - 6 << "' fill='" << (k++ % 2 ? "#9ecae1" : "#c6dbef") << "'><title>"
      << xml_escape(str(ph, "label")) << " (" << fmt(num(ph, "start_s", 0), 1) << "-"
      << fmt(num(ph, "end_s", end), 1) << " s)</title></rect>";
    if (x1 - x0 > 60)
      s << "<text x='" << x0 + 3 << "' y='" << Y("phase") + 15 << "' font-size='10'>"
        << xml_escape(str(ph, "label").substr(0, static_cast<std::size_t>((x1 - x0) / 6)))
        << "</text>";
  }
  std::map<std::string, std::string> colour;
  int c = 0;
  for (const Json& i : a["instruments"]) colour[str(i, "name")] = kColours[c++ % 6];
  for (const Json& iv : a["intervals"]) {
    const std::string r = str(iv, "row");
    const double x0 = X(num(iv, "start_s", 0)), x1 = X(num(iv, "end_s", end));
    std::string fill = colour.count(r)      ? colour[r]
                       : r == "fluoroscopy" ? "#bdbdbd"
                       : r == "cine"        ? "#636363"
                       : r == "injection"   ? "#6baed6"
                       : r == "inflation"   ? "#fd8d3c"
                                            : "#74c476";
    s << "<rect x='" << x0 << "' y='" << Y(r) + 4 << "' width='" << std::max(1.0, x1 - x0)
      << "' height='" << rh - 8 << "' fill='" << fill << "'><title>" << xml_escape(r) << ' '
      << fmt(num(iv, "start_s", 0), 2) << "-" << fmt(num(iv, "end_s", end), 2)
      << " s</title></rect>";
  }
  int n = 1;
  for (const Json& e : a["events"]) {
    const double x = X(num(e, "time_s", 0));
    s << "<g><line x1='" << x << "' x2='" << x << "' y1='" << top << "' y2='" << Y("events") + rh
      << "' stroke='#d62728' stroke-width='0.6' stroke-dasharray='2,2'/><circle cx='" << x
      << "' cy='" << Y("events") + 11 << "' r='7' fill='#d62728'/><text x='" << x << "' y='"
      << Y("events") + 15 << "' font-size='9' fill='white' text-anchor='middle'>" << n
      << "</text><title>" << n << ": " << xml_escape(str(e, "what")) << " ("
      << xml_escape(str(e, "instrument")) << ") at " << fmt(num(e, "time_s", 0), 2)
      << " s</title></g>";
    ++n;
  }
  // Time axis
  const double ya = top + rh * static_cast<double>(rows.size());
  const double tick = span > 120 ? 20 : span > 40 ? 10 : span > 10 ? 2 : 0.5;
  for (double t = 0; t <= span + 1e-9; t += tick)
    s << "<text x='" << X(t) << "' y='" << ya + 16 << "' font-size='10' text-anchor='middle'>"
      << fmt(t, tick < 1 ? 1 : 0) << "</text>";
  s << "<text x='" << W - 10 << "' y='" << ya + 16 << "' font-size='10' text-anchor='end'>s"
    << "</text></svg>";
  rows_out = rows;
  return s.str();
}

// A frames.csv row's pose into `pose`: the table's pan, and the angles, distances and field where
// the row has them (runs written before the poses were recorded have the pan alone).
void read_frame_pose(const std::vector<double>& row, CArmPose& pose) {
  pose.isocentre = Vec3(row[2], row[3], row[4]) * 1e-3;
  if (row.size() < 10) return;
  pose.primary_deg = row[5];
  pose.secondary_deg = row[6];
  pose.sid = row[7] * 1e-3;
  pose.sod = row[8] * 1e-3;
  pose.fov = row[9] * 1e-3;
}

// The tips' paths (series.csv, rest anatomy) over an angiogram frame, projected through the
// frame's C-arm pose: its own angles, distances and field where frames.csv has them (a trainee
// may have turned or zoomed the C-arm), else the scenario's (the view) with the frame's pan.
std::string path_svg(const Run& run, const Series& series, const Series* frames, int frame,
                     std::string& caption) {
  const Json& v = (*run.a)["view"];
  CArmPose pose;
  pose.primary_deg = num(v, "primary_deg", 0);
  pose.secondary_deg = num(v, "secondary_deg", 0);
  pose.sid = num(v, "sid_mm", 1200) * 1e-3;
  pose.sod = num(v, "sod_mm", 780) * 1e-3;
  pose.fov = num(v, "fov_mm", 200) * 1e-3;
  const double size = num(v, "size_px", 512);
  std::string image;
  if (frames && frame >= 0) {
    read_frame_pose(frames->rows[static_cast<std::size_t>(frame)], pose);
    const fs::path f = frame_file(run.dir, frame);
    if (fs::exists(f)) image = "data:image/png;base64," + base64(slurp(f, "a frame"));
  }
  std::vector<std::vector<Eigen::Vector2d>> paths;
  std::vector<std::string> names;
  double minx = 1e300, maxx = -1e300, miny = 1e300, maxy = -1e300;
  for (const Json& inst : (*run.a)["instruments"]) {
    const std::string name = str(inst, "name");
    const int cx = series.column(name + "_tip_x_mm"), cy = series.column(name + "_tip_y_mm"),
              cz = series.column(name + "_tip_z_mm");
    if (cx < 0 || cy < 0 || cz < 0) continue;
    std::vector<Eigen::Vector2d> pts;
    for (const auto& r : series.rows) {
      if (!std::isfinite(r[static_cast<std::size_t>(cx)]) ||
          !std::isfinite(r[static_cast<std::size_t>(cy)]) ||
          !std::isfinite(r[static_cast<std::size_t>(cz)]))
        continue;
      const Vec3 p = Vec3(r[static_cast<std::size_t>(cx)], r[static_cast<std::size_t>(cy)],
                          r[static_cast<std::size_t>(cz)]) *
                     1e-3;
      const Eigen::Vector2d d = project_to_detector(pose, p);
      const Eigen::Vector2d px((d.x() / pose.fov + 0.5) * size, (0.5 - d.y() / pose.fov) * size);
      pts.push_back(px);
      minx = std::min(minx, px.x());
      maxx = std::max(maxx, px.x());
      miny = std::min(miny, px.y());
      maxy = std::max(maxy, px.y());
    }
    paths.push_back(std::move(pts));
    names.push_back(name);
  }
  // Without a frame, the view box fits the paths.
  double vx = 0, vy = 0, vw = size, vh = size;
  if (image.empty() && maxx > minx) {
    const double m = 0.05 * std::max(maxx - minx, maxy - miny);
    vx = minx - m;
    vy = miny - m;
    vw = vh = std::max(maxx - minx, maxy - miny) + 2 * m;
  }
  std::ostringstream s;
  s << "<svg xmlns='http://www.w3.org/2000/svg' id='tippath' viewBox='" << vx << ' ' << vy << ' '
    << vw << ' ' << vh << "' width='512' height='512'>";
  if (!image.empty())
    s << "<image href='" << image << "' x='0' y='0' width='" << size << "' height='" << size
      << "'/>";
  else
    s << "<rect x='" << vx << "' y='" << vy << "' width='" << vw << "' height='" << vh
      << "' fill='#222'/>";
  const double sw = std::max(1.0, vw / 300);
  for (std::size_t k = 0; k < paths.size(); ++k) {
    s << "<polyline fill='none' stroke='" << kColours[k % 6] << "' stroke-width='" << sw
      << "' stroke-opacity='0.85' points='";
    for (const auto& p : paths[k]) s << fmt(p.x(), 1) << ',' << fmt(p.y(), 1) << ' ';
    s << "'><title>" << xml_escape(names[k]) << "</title></polyline>";
  }
  s << "</svg>";
  caption = image.empty()
                ? "no fluoroscopy frames in this run (--no-frames): the paths alone, "
                  "in the scenario's view"
                : "frame " + std::to_string(frame) +
                      " at t = " + fmt(frames->rows[static_cast<std::size_t>(frame)][1], 2) + " s";
  return s.str();
}

// Plots: dygraphs data as [[t, a, b, ...], ...] with labels, nulls for gaps.
Json plot(const Series& s, const std::string& title, const std::string& ylabel,
          const std::vector<std::pair<std::string, std::string>>& cols,  // column, label
          const std::vector<std::pair<std::string, double>>& constants = {},
          bool instrument_colours = false) {
  Json labels = Json::array({"time (s)"});
  std::vector<int> idx;
  for (const auto& [c, l] : cols) {
    const int k = s.column(c);
    if (k < 0) continue;
    idx.push_back(k);
    labels.push_back(l);
  }
  for (const auto& [l, v] : constants) labels.push_back(l);
  Json data = Json::array();
  for (const auto& r : s.rows) {
    Json row = Json::array({r[0]});
    for (int k : idx) {
      const double v = r[static_cast<std::size_t>(k)];
      row.push_back(std::isfinite(v) ? Json(v) : Json(nullptr));
    }
    for (const auto& [l, v] : constants) row.push_back(v);
    data.push_back(row);
  }
  Json out = {{"title", title}, {"ylabel", ylabel}, {"labels", labels}, {"data", data}};
  if (instrument_colours) {  // the timeline's and the paths' colours, by instrument order
    Json c = Json::array();
    for (std::size_t k = 0; k < cols.size(); ++k) c.push_back(kColours[k % 6]);
    for (std::size_t k = 0; k < constants.size(); ++k) c.push_back(k == 0 ? "#555555" : "#aaaaaa");
    out["colors"] = c;
  }
  return out;
}

std::string dygraphs_js(const ReportOptions& o) {
  std::string js = slurp(o.plot_library.empty() ? fs::path(VCSIM_DYGRAPHS_JS) : o.plot_library,
                         "the plotting library (Debian libjs-dygraphs)");
  // Inlined, the page has no map to point at.
  const std::size_t m = js.rfind("//# sourceMappingURL=");
  if (m != std::string::npos) js.erase(m);
  const std::string close = "</script";
  for (std::size_t p = js.find(close); p != std::string::npos; p = js.find(close, p + 2))
    js.replace(p, 2, "<\\/");
  return js;
}

mu::mustache load_template(const fs::path& file) {
  mu::mustache t{slurp(file, "the report's page template (Mustache)")};
  if (!t.is_valid())
    throw InputError(file.string(), "template",
                     "expected a valid Mustache template: " + t.error_message());
  return t;
}

std::string value_text(const Json& v, int decimals) {
  if (v.is_null()) return "n/a";
  if (v.is_boolean()) return v.get<bool>() ? "yes" : "no";
  if (v.is_number_integer()) return std::to_string(v.get<long long>());
  return fmt(v.get<double>(), decimals);
}

}  // namespace

fs::path default_report_template() {
  if (const char* d = std::getenv("VCSIM_REPORT_TEMPLATE"); d && *d) return d;
  return VCSIM_DEFAULT_REPORT_TEMPLATE;
}

std::string read_run_metrics(const fs::path& run_dir) {
  return load_run(run_dir).metrics.dump();
}

fs::path write_report(const fs::path& run_dir, const fs::path& out_arg, const ReportOptions& o) {
  const Run run = load_run(run_dir);
  const Json& a = *run.a;
  const Json& m = run.metrics;
  const Series series = read_csv(run_dir / "series.csv", "series.csv (written by vcsim run)");
  if (series.columns.empty() || series.columns[0] != "time_s")
    throw InputError((run_dir / "series.csv").string(), "line 1", "expected time_s first");
  std::optional<Series> frames;
  if (fs::exists(run_dir / "frames.csv")) {
    frames = read_csv(run_dir / "frames.csv", "frames.csv");
    // Runs written before the poses were recorded have the pan only.
    if (frames->columns.size() != 5 && frames->columns.size() != 10)
      throw InputError((run_dir / "frames.csv").string(), "line 1",
                       "expected frame, time, the isocentre's three coordinates and the C-arm's "
                       "primary and secondary angles, sid, sod and field (or the pan alone)");
    if (frames->columns.size() == 10) {
      // A pose the C-arm cannot take would project the paths nowhere.
      for (std::size_t k = 0; k < frames->rows.size(); ++k) {
        const auto& row = frames->rows[k];
        const std::string where = (run_dir / "frames.csv").string() + " frame " + std::to_string(k);
        for (std::size_t c = 2; c < row.size(); ++c)
          if (!std::isfinite(row[c]))
            throw InputError(where, frames->columns[c], "expected a number");
        CArmPose pose;
        read_frame_pose(row, pose);
        pose.validate(where);
      }
    }
  }
  const double end = num(a, "procedure_time_s", num(m, "sim_time_s", 0));
  const fs::path tmpl_file = o.template_file.empty() ? default_report_template() : o.template_file;
  mu::mustache tmpl = load_template(tmpl_file);

  mu::data d;
  d.set("scenario", str(m, "scenario"));
  d.set("outcome", str(m, "outcome"));
  d.set("success", mu::data(m.contains("success") && m["success"] == true));
  d.set("input", m.contains("input") ? str(m["input"], "type") : "");
  d.set("procedure_time", fmt(end, 1));
  d.set("state_hash", str(m, "state_hash"));
  d.set("beam_source", str(a["beam"], "source"));
  // Metrics against references
  const Json& sum = a["summary"];
  mu::list rows;
  for (const Reference& r : load_references()) {
    if (!sum.contains(r.key)) continue;
    const Json& v = sum[r.key];
    mu::object row{{"label", r.label},
                   {"unit", r.unit},
                   {"value", value_text(v, r.decimals)},
                   {"range", range_text(r)},
                   {"source", r.source}};
    row["status"] = status_of(v, r);
    rows.push_back(row);
  }
  d.set("metrics", rows);
  // Instruments
  mu::list insts;
  for (const Json& i : a["instruments"]) {
    insts.push_back(mu::object{
        {"name", str(i, "name")},
        {"kind", str(i, "kind")},
        {"catalogue", str(i, "catalogue")},
        {"insertions", fmt(num(i, "insertions", 0), 0)},
        {"tip_path", fmt(num(i, "tip_path_mm", 0), 0)},
        {"peak_hand", fmt(num(i, "peak_hand_force_n", 0), 2)},
        {"peak_wall", fmt(num(i, "peak_tip_wall_force_n", 0), 2)},
        {"threshold", i.contains("force_threshold_n") && i["force_threshold_n"].is_number()
                          ? fmt(i["force_threshold_n"].get<double>(), 2)
                          : std::string("-")},
        {"events", std::to_string(i.contains("force_events") && i["force_events"].is_array()
                                      ? i["force_events"].size()
                                      : 0)},
        {"wrong", fmt(num(i, "wrong_branch_time_s", 0), 2)},
        {"entries", fmt(num(i, "wrong_branch_entries", 0), 0)}});
  }
  d.set("instruments", insts);
  // Timeline and events
  std::vector<std::string> trows;
  d.set("timeline_svg", timeline_svg(a, end, trows));
  mu::list evs;
  int n = 1;
  for (const Json& e : a["events"])
    evs.push_back(mu::object{{"n", std::to_string(n++)},
                             {"time", fmt(num(e, "time_s", 0), 2)},
                             {"what", str(e, "what")},
                             {"instrument", str(e, "instrument")}});
  d.set("events", evs);
  // Key frames: first engagement, lesion crossed, before and after treatment
  std::vector<FramePick> picks;
  double engaged = -1, crossed = -1, first_inflation = -1, last_inflation = -1;
  for (const Json& e : a["events"]) {
    const std::string w = str(e, "what");
    const double t = num(e, "time_s", -1);
    if (w == "engaged" && engaged < 0) engaged = t;
    if (w.rfind("lesion ", 0) == 0 && crossed < 0) crossed = t;
  }
  for (const Json& iv : a["intervals"])
    if (str(iv, "row") == "inflation") {
      if (first_inflation < 0) first_inflation = num(iv, "start_s", -1);
      last_inflation = num(iv, "end_s", -1);
    }
  double before = -1, after = -1;
  for (const Json& inj : a["contrast"]["injections"]) {
    const double t = num(inj, "end_s", -1);
    if (first_inflation >= 0 && t <= first_inflation) before = t;
    if (last_inflation >= 0 && t >= last_inflation) after = t;
  }
  if (engaged >= 0) picks.push_back({"guide engaged", engaged + 0.5});
  if (crossed >= 0) picks.push_back({"lesion crossed", crossed});
  if (before >= 0) picks.push_back({"angiogram before treatment", before});
  if (after >= 0) picks.push_back({"angiogram after treatment", after});
  if (picks.empty()) picks.push_back({"last frame", end});
  mu::list frame_list;
  int angiogram = -1;
  if (frames && !frames->rows.empty()) {
    for (const FramePick& p : picks) {
      const int k = frame_at(*frames, p.time);
      const fs::path f = frame_file(run_dir, k);
      if (k < 0 || !fs::exists(f)) continue;
      frame_list.push_back(
          mu::object{{"caption", p.caption},
                     {"time", fmt(frames->rows[static_cast<std::size_t>(k)][1], 2)},
                     {"src", "data:image/png;base64," + base64(slurp(f, "a frame"))}});
    }
    // The angiogram under the tip path: after treatment, else the last injection, else last.
    double t = after >= 0 ? after : -1;
    if (t < 0 && !a["contrast"]["injections"].empty())
      t = num(a["contrast"]["injections"].back(), "end_s", end);
    angiogram = frame_at(*frames, t >= 0 ? t : end);
  }
  d.set("frames", frame_list);
  d.set("has_frames", mu::data(!frame_list.empty()));
  std::string caption;
  d.set("path_svg", path_svg(run, series, frames ? &*frames : nullptr, angiogram, caption));
  d.set("path_caption", caption);
  mu::list legend;
  int c = 0;
  for (const Json& i : a["instruments"])
    legend.push_back(mu::object{{"name", str(i, "name")}, {"colour", kColours[c++ % 6]}});
  d.set("legend", legend);
  // Plots
  std::vector<std::pair<std::string, std::string>> force, wall, depth;
  double cath = num(a["settings"], "catheter_force_n", 1.0);
  double wire = num(a["settings"], "coronary_wire_force_n", 0.15);
  for (const Json& i : a["instruments"]) {
    const std::string nm = str(i, "name");
    force.push_back({nm + "_force_n", nm});
    wall.push_back({nm + "_tip_wall_force_n", nm});
    depth.push_back({nm + "_depth_mm", nm});
  }
  Json plots = Json::array();
  plots.push_back(plot(series, "Hand force per instrument (N, the largest in each 50 ms)", "N",
                       force, {}, true));
  plots.push_back(
      plot(series, "Tip contact force on the vessel wall (N, low-passed) and thresholds", "N", wall,
           {{"catheter threshold", cath}, {"coronary wire threshold", wire}}, true));
  plots.push_back(plot(series, "Insertion depth (mm)", "mm", depth, {}, true));
  plots.push_back(plot(series, "Contrast: syringe flow and volume injected", "ml/s, ml",
                       {{"syringe_flow_ml_s", "flow (ml/s)"}, {"contrast_ml", "volume (ml)"}}));
  plots.push_back(plot(series, "Fluoroscopy: beam-on time and estimated air kerma", "s, mGy",
                       {{"beam_on_s", "beam on (s)"}, {"air_kerma_mgy", "air kerma (mGy)"}}));
  d.set("plots_json", script_json(plots));
  d.set("plot_library", dygraphs_js(o));
  const Json& dose = a["dose"];
  d.set("dose_model",
        cat("reference air kerma = ", fmt(num(a["settings"], "fluoro_kerma_rate_mgy_min", 0), 1),
            " mGy/min x fluoroscopy time + ",
            fmt(num(a["settings"], "cine_kerma_per_frame_mgy", 0), 2),
            " mGy x cine frames; kerma-area product = air kerma x ",
            fmt(num(dose, "field_area_cm2", 0), 0), " cm2 (the field at the reference point)"));

  const fs::path out = out_arg.empty() ? run_dir / "report.html" : out_arg;
  std::ofstream f(out, std::ios::binary);
  f << tmpl.render(d);
  if (!f) throw InputError(out.string(), "file", "expected a writable report file");
  return out;
}

void write_metrics_csv(std::span<const fs::path> run_dirs, const fs::path& out) {
  std::vector<Run> runs;
  for (const fs::path& d : run_dirs) runs.push_back(load_run(d));
  // Columns in the reference file's order (docs/assessment.md), then any others by name.
  std::vector<std::string> keys;
  for (const Reference& ref : load_references())
    for (const Run& r : runs)
      if ((*r.a)["summary"].contains(ref.key) &&
          std::find(keys.begin(), keys.end(), ref.key) == keys.end())
        keys.push_back(ref.key);
  for (const Run& r : runs)
    for (auto& [k, v] : (*r.a)["summary"].items())
      if (std::find(keys.begin(), keys.end(), k) == keys.end()) keys.push_back(k);
  std::ofstream f(out);
  f << "run,scenario,input";
  for (const auto& k : keys) f << ',' << k;
  f << '\n';
  for (const Run& r : runs) {
    std::string dir = r.dir.string();
    std::replace(dir.begin(), dir.end(), ',', ';');
    f << dir << ',' << str(r.metrics, "scenario") << ','
      << (r.metrics.contains("input") ? str(r.metrics["input"], "type") : "");
    for (const auto& k : keys) {
      f << ',';
      const Json& s = (*r.a)["summary"];
      if (s.contains(k) && s[k].is_number()) {
        if (s[k].is_number_integer())
          f << s[k].get<long long>();
        else
          f << fmt(s[k].get<double>(), 4);
      }
    }
    f << '\n';
  }
  if (!f) throw InputError(out.string(), "file", "expected a writable CSV file");
}

void write_compare_report(std::span<const fs::path> run_dirs, const fs::path& out,
                          const ReportOptions& o) {
  if (run_dirs.empty()) throw InputError("report compare", "RUN_DIR", "expected run folders");
  std::vector<Run> runs;
  for (const fs::path& d : run_dirs) runs.push_back(load_run(d));
  const std::vector<Reference> refs = load_references();
  fs::path tmpl_file = o.template_file.empty()
                           ? default_report_template().parent_path() / "compare.html.mustache"
                           : o.template_file;
  mu::mustache tmpl = load_template(tmpl_file);
  mu::data d;
  mu::list header;
  for (std::size_t k = 0; k < runs.size(); ++k)
    header.push_back(mu::object{
        {"n", std::to_string(k + 1)},
        {"dir", (runs[k].dir.parent_path().filename() / runs[k].dir.filename()).string()}});
  d.set("runs", header);
  mu::list rows;
  Json plots = Json::array();
  for (const Reference& r : refs) {
    mu::list cells;
    Json data = Json::array();
    bool any = false;
    for (std::size_t k = 0; k < runs.size(); ++k) {
      const Json& s = (*runs[k].a)["summary"];
      const Json v = s.contains(r.key) ? s[r.key] : Json(nullptr);
      cells.push_back(
          mu::object{{"value", value_text(v, r.decimals)}, {"status", status_of(v, r)}});
      data.push_back({static_cast<double>(k + 1), v.is_number() ? v : Json(nullptr)});
      any = any || v.is_number();
    }
    rows.push_back(mu::object{
        {"label", r.label}, {"unit", r.unit}, {"range", range_text(r)}, {"cells", cells}});
    if (any)
      plots.push_back({{"title", r.label + (r.unit.empty() ? "" : " (" + r.unit + ")")},
                       {"ylabel", r.unit},
                       {"labels", {"session", r.label}},
                       {"data", data}});
  }
  d.set("metrics", rows);
  d.set("plots_json", script_json(plots));
  d.set("plot_library", dygraphs_js(o));
  std::ofstream f(out, std::ios::binary);
  f << tmpl.render(d);
  if (!f) throw InputError(out.string(), "file", "expected a writable report file");
}

}  // namespace vcsim
