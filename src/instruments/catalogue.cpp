// Catalogue files -> InstrumentSpec (SI). Every field is checked here, once, with the file and
// the field path in the message; the rest of the engine trusts the spec.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <numbers>
#include <sstream>

#include "json_fields.h"
#include "vcsim/instruments.h"
#include "vcsim/units.h"

namespace vcsim {

using internal::Json;
using internal::JsonFields;

namespace {

constexpr double kPerCm = 100.0;  // 1/cm -> 1/m
// Rounding room (m) for tolerances written in mm, so that "within 0.05 mm" accepts 0.05 mm.
constexpr double kSlack = 1e-12;

bool valid_name(const std::string& s) {
  if (s.empty() || s.size() > 64) return false;
  return std::all_of(s.begin(), s.end(), [](char c) {
    return (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '-' || c == '_' || c == '.';
  });
}

// Exactly one of the keys, converted by its factor; names both keys in the error.
double one_of(JsonFields& f, std::initializer_list<std::pair<const char*, double>> keys,
              bool required, double lo, double hi) {
  const char* found = nullptr;
  double value = 0.0;
  std::string names;
  for (auto [key, factor] : keys) {
    if (!names.empty()) names += ", ";
    names += key;
    if (!f.has(key)) continue;
    if (found) {
      std::string what = "expected only one of ";
      what += found;
      what += " and ";
      what += key;
      f.fail(key, what);
    }
    found = key;
    value = require_in_range(f.number(key), lo / factor, hi / factor, f.source(), f.field(key)) *
            factor;
  }
  if (!found && required) {
    throw InputError(f.source(), f.path().empty() ? names : f.field(names),
                     "expected one of these keys");
  }
  return value;
}

TipSection parse_section(const Json& j, const std::string& source, const std::string& path) {
  JsonFields s(j, source, path);
  const bool straight = s.has("straight_mm"), arc = s.has("arc");
  if (straight == arc) {
    throw InputError(source, path, "expected exactly one of straight_mm or arc");
  }
  TipSection out;
  if (straight) {
    out = TipSection::straight(s.positive("straight_mm") * kMm);
  } else {
    JsonFields a = s.object("arc");
    const double radius = a.positive("radius_mm") * kMm;
    const double angle = a.number("angle_deg");
    if (angle == 0.0 || std::abs(angle) > 720.0) {
      std::string what = "expected a nonzero angle within [-720, 720] degrees, got ";
      what += internal::describe_json(a.require("angle_deg"));
      a.fail("angle_deg", what);
    }
    const double plane = a.number_or("plane_deg", 0.0);
    if (std::abs(plane) > 360.0) a.fail("plane_deg", "expected a plane angle within [-360, 360]");
    a.finish();
    out = TipSection::arc(radius, angle * kDeg, plane * kDeg);
  }
  s.finish();
  return out;
}

InstrumentFriction parse_friction(JsonFields f) {
  InstrumentFriction out;
  out.vessel_static = f.nonnegative("vessel_static");
  out.vessel_dynamic = f.nonnegative("vessel_dynamic");
  out.lumen = f.nonnegative("lumen");
  for (auto [key, v] :
       {std::pair{"vessel_static", out.vessel_static},
        std::pair{"vessel_dynamic", out.vessel_dynamic}, std::pair{"lumen", out.lumen}}) {
    if (v > 2.0) f.fail(key, "expected a coefficient of at most 2");
  }
  if (out.vessel_dynamic > out.vessel_static) {
    f.fail("vessel_dynamic", "expected at most vessel_static");
  }
  f.finish();
  return out;
}

// A braid lies in the wall: its two crossing layers of flat wire must fit the wall's thickness.
BraidSpec parse_braid(JsonFields b, double outer_diameter, double inner_diameter) {
  b.keys({"wires", "wire_width_mm", "wire_thickness_mm", "angle_deg", "modulus_gpa"});
  BraidSpec out;
  out.wires = b.integer_or("wires", 2, 128, -1);
  if (out.wires < 0) b.fail("wires", "required: the braid's carriers (2-128)");
  if (out.wires % 2 != 0) {
    b.fail("wires", internal::cat("expected an even count (half each way round), got ",
                                  std::to_string(out.wires)));
  }
  out.wire_width = b.in_range("wire_width_mm", 0.0, 1.0) * kMm;
  out.wire_thickness = b.in_range("wire_thickness_mm", 0.0, 1.0) * kMm;
  out.angle = b.in_range("angle_deg", 0.0, 89.0) * kDeg;
  out.modulus = b.in_range("modulus_gpa", 0.0, 1000.0) * 1e9;
  const double wall = 0.5 * (outer_diameter - inner_diameter);
  if (2.0 * out.wire_thickness > wall) {
    char text[96];
    std::snprintf(text, sizeof text, "expected two layers to fit the wall (%.4g mm each at most)",
                  0.5 * wall / kMm);
    b.fail("wire_thickness_mm", text);
  }
  b.finish();
  return out;
}

InstrumentRadiopacity parse_radiopacity(JsonFields r, double length) {
  InstrumentRadiopacity out;
  out.material = r.string("material");
  if (out.material.empty()) r.fail("material", "expected a material name");
  out.attenuation_60kev = r.nonnegative("attenuation_60kev_per_cm") * kPerCm;
  out.attenuation_80kev = r.nonnegative("attenuation_80kev_per_cm") * kPerCm;
  out.coil_length = r.nonnegative_or("coil_length_mm", 0.0) * kMm;
  if (out.coil_length > length) r.fail("coil_length_mm", "expected at most length_mm");
  const bool coil = out.coil_length > 0.0;
  // The coil's attenuation is needed exactly when there is a coil.
  for (auto [key, dst] :
       {std::pair{"coil_attenuation_60kev_per_cm", &out.coil_attenuation_60kev},
        std::pair{"coil_attenuation_80kev_per_cm", &out.coil_attenuation_80kev}}) {
    if (r.has(key) != coil) {
      r.fail(key, coil ? "expected this key (coil_length_mm > 0)"
                       : "expected no coil attenuation without coil_length_mm > 0");
    }
    if (coil) *dst = r.nonnegative(key) * kPerCm;
  }
  if (const Json* m = r.get("markers_mm_from_tip")) {
    const std::string field = r.field("markers_mm_from_tip");
    if (!m->is_array()) {
      throw InputError(r.source(), field,
                       internal::cat("expected an array, got ", internal::describe_json(*m)));
    }
    for (std::size_t i = 0; i < m->size(); ++i) {
      const std::string fi = internal::index_path(field, i);
      const double d = require_nonnegative(r.as_number((*m)[i], fi), r.source(), fi) * kMm;
      if (d > length) throw InputError(r.source(), fi, "expected at most length_mm");
      out.markers.push_back(d);
    }
  }
  r.finish();
  return out;
}

std::string num(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%g", v);
  return buf;
}

// The compliance chart: [[pressure_atm, diameter_mm], ...], pressures strictly increasing,
// diameters positive and non-decreasing (a balloon does not shrink as the pressure rises).
void parse_chart(JsonFields& b, BalloonSpec& out) {
  const Json& chart = b.array("chart");
  const std::string field = b.field("chart");
  if (chart.size() < 2) {
    throw InputError(b.source(), field,
                     "expected at least two [pressure_atm, diameter_mm] entries");
  }
  for (std::size_t i = 0; i < chart.size(); ++i) {
    const std::string fi = internal::index_path(field, i);
    const Json& e = chart[i];
    if (!e.is_array() || e.size() != 2) {
      throw InputError(
          b.source(), fi,
          internal::cat("expected [pressure_atm, diameter_mm], got ", internal::describe_json(e)));
    }
    const std::string fp = internal::index_path(fi, 0), fd = internal::index_path(fi, 1);
    const double p = require_in_range(b.as_number(e[0], fp), 0.0, 50.0, b.source(), fp);
    const double d = require_in_range(b.as_number(e[1], fd), 0.0, 10.0, b.source(), fd);
    if (i > 0 && !(p * kAtm > out.chart_pressure.back())) {
      throw InputError(b.source(), fp,
                       internal::cat("expected a pressure above the previous entry's ",
                                     num(out.chart_pressure.back() / kAtm),
                                     " atm (strictly increasing), got ", num(p)));
    }
    if (i > 0 && d * kMm < out.chart_diameter.back()) {
      throw InputError(b.source(), fd,
                       internal::cat("expected at least the previous entry's ",
                                     num(out.chart_diameter.back() / kMm),
                                     " mm (diameters non-decreasing), got ", num(d)));
    }
    out.chart_pressure.push_back(p * kAtm);
    out.chart_diameter.push_back(d * kMm);
  }
}

// `shaft_length` (m) bounds where the balloon may sit.
BalloonSpec parse_balloon(JsonFields b, double shaft_length) {
  b.keys({"compliance", "nominal_diameter_mm", "length_mm", "distal_offset_mm",
          "nominal_pressure_atm", "rated_burst_pressure_atm", "crossing_profile_mm",
          "lengthening_at_rbp_mm", "chart", "comment"});
  BalloonSpec out;
  const std::string compliance = b.string("compliance");
  if (compliance == "semi-compliant") {
    out.compliance = BalloonSpec::Compliance::kSemiCompliant;
  } else if (compliance == "non-compliant") {
    out.compliance = BalloonSpec::Compliance::kNonCompliant;
  } else {
    b.fail("compliance", internal::cat("expected \"semi-compliant\" or \"non-compliant\", got \"",
                                       compliance, "\""));
  }
  out.nominal_diameter = b.in_range("nominal_diameter_mm", 0.0, 10.0) * kMm;
  out.length = b.in_range("length_mm", 0.0, 100.0) * kMm;
  out.distal_offset = b.nonnegative("distal_offset_mm") * kMm;
  if (out.distal_offset + out.length > shaft_length) {
    b.fail("distal_offset_mm",
           "expected the balloon (distal_offset_mm + length_mm) within the shaft's length_mm");
  }
  out.nominal_pressure = b.in_range("nominal_pressure_atm", 0.0, 50.0) * kAtm;
  out.rated_burst_pressure = b.in_range("rated_burst_pressure_atm", 0.0, 50.0) * kAtm;
  if (!(out.rated_burst_pressure > out.nominal_pressure)) {
    b.fail("rated_burst_pressure_atm", internal::cat("expected more than nominal_pressure_atm (",
                                                     num(out.nominal_pressure / kAtm), " atm)"));
  }
  out.crossing_profile = b.in_range("crossing_profile_mm", 0.0, 10.0) * kMm;
  out.lengthening = b.nonnegative("lengthening_at_rbp_mm") * kMm;
  if (out.lengthening > out.length) b.fail("lengthening_at_rbp_mm", "expected at most length_mm");

  parse_chart(b, out);
  const std::string chart = b.field("chart");
  const std::size_t last = out.chart_pressure.size() - 1;
  if (out.chart_pressure.front() > out.nominal_pressure) {
    const std::string f = internal::index_path(internal::index_path(chart, 0), 0);
    throw InputError(b.source(), f,
                     internal::cat("expected the first pressure at most nominal_pressure_atm (",
                                   num(out.nominal_pressure / kAtm), " atm)"));
  }
  if (out.chart_pressure.back() < out.rated_burst_pressure) {
    const std::string f = internal::index_path(internal::index_path(chart, last), 0);
    throw InputError(b.source(), f,
                     internal::cat("expected the last pressure at least rated_burst_pressure_atm (",
                                   num(out.rated_burst_pressure / kAtm), " atm)"));
  }
  if (out.crossing_profile > out.chart_diameter.front()) {
    b.fail("crossing_profile_mm",
           internal::cat("expected at most the chart's first diameter (",
                         num(out.chart_diameter.front() / kMm),
                         " mm): the folded balloon only grows as it unfolds"));
  }
  // The chart must carry the label: its nominal pressure gives its nominal diameter.
  const double at_nominal = out.diameter_at(out.nominal_pressure);
  if (std::abs(at_nominal - out.nominal_diameter) > 0.01 * out.nominal_diameter + kSlack) {
    b.fail("chart",
           internal::cat("expected ", num(out.nominal_diameter / kMm),
                         " mm at nominal_pressure_atm (within 1 % of nominal_diameter_mm), got ",
                         num(at_nominal / kMm), " mm"));
  }
  b.finish();
  return out;
}

// A stent crimped on `balloon`: the same labelled diameter, no longer than the balloon.
StentSpec parse_stent(JsonFields t, const BalloonSpec& balloon) {
  t.keys({"nominal_diameter_mm", "length_mm", "strut_thickness_um", "material",
          "attenuation_60kev_per_cm", "attenuation_80kev_per_cm", "metal_coverage", "acute_recoil",
          "foreshortening", "crimped_profile_mm", "comment"});
  StentSpec out;
  out.nominal_diameter = t.in_range("nominal_diameter_mm", 0.0, 10.0) * kMm;
  if (std::abs(out.nominal_diameter - balloon.nominal_diameter) > 0.05 * kMm + kSlack) {
    t.fail("nominal_diameter_mm",
           internal::cat("expected the delivery balloon's nominal diameter (",
                         num(balloon.nominal_diameter / kMm), " mm, within 0.05 mm)"));
  }
  out.length = t.in_range("length_mm", 0.0, 100.0) * kMm;
  if (out.length > balloon.length) {
    t.fail("length_mm", internal::cat("expected at most the balloon's length_mm (",
                                      num(balloon.length / kMm), " mm)"));
  }
  out.strut_thickness = t.in_range("strut_thickness_um", 0.0, 1000.0) * kUm;
  out.material = t.string("material");
  if (out.material.empty()) t.fail("material", "expected a material name");
  out.attenuation_60kev = t.nonnegative("attenuation_60kev_per_cm") * kPerCm;
  out.attenuation_80kev = t.nonnegative("attenuation_80kev_per_cm") * kPerCm;
  out.metal_coverage = t.number("metal_coverage");
  if (!(out.metal_coverage > 0.0 && out.metal_coverage < 1.0)) {
    t.fail("metal_coverage", "expected a fraction in (0, 1)");
  }
  for (auto [key, dst] : {std::pair{"acute_recoil", &out.acute_recoil},
                          std::pair{"foreshortening", &out.foreshortening}}) {
    *dst = t.number(key);
    if (!(*dst >= 0.0 && *dst < 1.0)) t.fail(key, "expected a fraction in [0, 1)");
  }
  out.crimped_profile = t.in_range("crimped_profile_mm", 0.0, 10.0) * kMm;
  if (!(out.crimped_profile > balloon.crossing_profile)) {
    t.fail("crimped_profile_mm",
           internal::cat("expected more than the balloon's crossing_profile_mm (",
                         num(balloon.crossing_profile / kMm), " mm): the stent is crimped on it"));
  }
  if (!(out.crimped_profile < out.nominal_diameter)) {
    t.fail("crimped_profile_mm", "expected less than nominal_diameter_mm");
  }
  t.finish();
  return out;
}

}  // namespace

const char* to_string(InstrumentKind k) {
  switch (k) {
    case InstrumentKind::kGuidewire:
      return "guidewire";
    case InstrumentKind::kCatheter:
      return "catheter";
    case InstrumentKind::kBalloon:
      return "balloon";
    case InstrumentKind::kStent:
      return "stent";
  }
  return "unknown";
}

double InstrumentSpec::polar_moment() const {
  const double ro = 0.5 * outer_diameter, ri = 0.5 * inner_diameter;
  return 0.5 * std::numbers::pi * (ro * ro * ro * ro - ri * ri * ri * ri);
}

double InstrumentSpec::torsional_rigidity() const {
  const double ro = 0.5 * outer_diameter, ri = 0.5 * inner_diameter;
  double gj = youngs_modulus / (2.0 * (1.0 + poisson)) * polar_moment();
  if (braid) {
    const double r = 0.5 * (ro + ri), s = std::sin(braid->angle), c = std::cos(braid->angle);
    gj += braid->wires * braid->modulus * braid->wire_width * braid->wire_thickness * r * r * s *
          s * c;
  }
  return gj;
}

double InstrumentSpec::shaped_length() const {
  double s = 0.0;
  for (const auto& t : tip_shape) s += t.length;
  return s;
}

InstrumentSpec parse_instrument(std::string_view json_text, const std::string& source,
                                const std::string& expected_name) {
  const Json doc = internal::parse_json_text(json_text, source);
  JsonFields f(doc, source, "");
  InstrumentSpec s;
  s.source = source;

  s.name = f.string("name");
  if (!valid_name(s.name)) {
    f.fail("name",
           internal::cat("expected 1-64 characters from a-z 0-9 - _ . , got \"", s.name, "\""));
  }
  if (!expected_name.empty() && s.name != expected_name) {
    f.fail("name",
           internal::cat("expected \"", expected_name, "\" (the file name), got \"", s.name, "\""));
  }
  s.description = f.string_or("description", "");
  f.get("comment");  // free text for editors, ignored

  const std::string kind = f.string("kind");
  if (kind == "guidewire") {
    s.kind = InstrumentKind::kGuidewire;
  } else if (kind == "catheter") {
    s.kind = InstrumentKind::kCatheter;
  } else if (kind == "balloon") {
    s.kind = InstrumentKind::kBalloon;
  } else if (kind == "stent") {
    s.kind = InstrumentKind::kStent;
  } else {
    f.fail("kind",
           internal::cat("expected \"guidewire\", \"catheter\", \"balloon\" or \"stent\", got \"",
                         kind, "\""));
  }

  s.length = f.in_range("length_mm", 0.0, 5000.0) * kMm;
  s.outer_diameter =
      one_of(f, {{"od_in", kInch}, {"od_fr", kFrench}, {"od_mm", kMm}}, true, 0.0, 10.0e-3);
  s.inner_diameter = one_of(f, {{"id_in", kInch}, {"id_mm", kMm}}, false, -1e-300, 10.0e-3);
  const char* id_key = f.has("id_in") ? "id_in" : "id_mm";
  // Every kind but a wire has a lumen; a balloon or stent catheter's is its wire lumen.
  if (s.kind != InstrumentKind::kGuidewire && !(s.inner_diameter > 0.0)) {
    f.fail(id_key, internal::cat("expected a positive inner diameter (id_mm or id_in) for a ",
                                 to_string(s.kind)));
  }
  if (s.inner_diameter >= s.outer_diameter) {
    f.fail(id_key, "expected an inner diameter less than the outer diameter");
  }

  s.youngs_modulus = f.in_range("youngs_modulus_gpa", 0.0, 1000.0) * 1e9;
  s.tip_length = f.nonnegative("tip_length_mm") * kMm;
  if (s.tip_length > s.length) f.fail("tip_length_mm", "expected at most length_mm");
  s.tip_modulus_ratio = f.in_range("tip_modulus_ratio", 0.0, 1.0);
  // A wire's core tapers proximal to its soft tip (docs/instruments.md, "Core taper").
  if (f.has("core_taper_mm")) {
    if (s.kind != InstrumentKind::kGuidewire) f.fail("core_taper_mm", "expected only on a wire");
    s.core_taper_length = f.nonnegative("core_taper_mm") * kMm;
    if (s.tip_length + s.core_taper_length > s.length) {
      f.fail("core_taper_mm", "expected at most length_mm less tip_length_mm");
    }
  }
  // A tapered tip (balloon catheters): the entry profile is the diameter that meets a lesion.
  if (f.has("tip_taper_mm")) {
    s.taper_length = f.in_range("tip_taper_mm", 0.0, 50.0) * kMm;
    if (s.taper_length > s.length) f.fail("tip_taper_mm", "expected at most length_mm");
    s.entry_profile = one_of(f, {{"tip_entry_profile_in", kInch}, {"tip_entry_profile_mm", kMm}},
                             true, 0.0, 10.0e-3);
    const char* key =
        f.has("tip_entry_profile_in") ? "tip_entry_profile_in" : "tip_entry_profile_mm";
    if (!(s.entry_profile > s.inner_diameter && s.entry_profile <= s.outer_diameter)) {
      f.fail(key, "expected more than the inner diameter and at most the outer diameter");
    }
  } else if (f.has("tip_entry_profile_in") || f.has("tip_entry_profile_mm")) {
    f.fail("tip_taper_mm", "expected with a tip entry profile (the length it tapers over)");
  }
  s.poisson = f.in_range_or("poisson", -1.0, 0.5, 0.3);
  if (f.has("braid")) {
    if (!(s.inner_diameter > 0.0)) f.fail("braid", "expected only on a tube (an id_mm or id_in)");
    s.braid = parse_braid(f.object("braid"), s.outer_diameter, s.inner_diameter);
  }
  s.density = f.in_range("density_kg_m3", 0.0, 25000.0);

  const Json& sections = f.array("tip_sections");
  for (std::size_t i = 0; i < sections.size(); ++i) {
    s.tip_shape.push_back(
        parse_section(sections[i], source, internal::index_path("tip_sections", i)));
  }
  if (s.shaped_length() > s.length) {
    f.fail("tip_sections", "expected the sections to be no longer than length_mm");
  }

  s.friction = parse_friction(f.object("friction"));
  s.radiopacity = parse_radiopacity(f.object("radiopacity"), s.length);

  // A balloon catheter carries a balloon, a stent system a stent on its delivery balloon; wires
  // and plain catheters carry neither.
  const bool has_balloon = f.has("balloon"), has_stent = f.has("stent");
  const bool wants_balloon = s.kind == InstrumentKind::kBalloon || s.kind == InstrumentKind::kStent;
  const bool wants_stent = s.kind == InstrumentKind::kStent;
  if (has_balloon != wants_balloon) {
    f.fail("balloon", wants_balloon
                          ? internal::cat("expected this section for kind \"", kind,
                                          s.kind == InstrumentKind::kStent
                                              ? "\" (a stent comes mounted on its balloon)"
                                              : "\"")
                          : internal::cat("expected no balloon on a ", kind,
                                          " (kind \"balloon\" or \"stent\" carries one)"));
  }
  if (has_stent != wants_stent) {
    f.fail("stent", wants_stent ? std::string("expected this section for kind \"stent\"")
                                : internal::cat("expected no stent on a ", kind,
                                                " (a stent system is kind \"stent\")"));
  }
  if (has_balloon) s.balloon = parse_balloon(f.object("balloon"), s.length);
  if (has_stent) s.stent = parse_stent(f.object("stent"), *s.balloon);
  f.finish();
  return s;
}

InstrumentSpec load_instrument(const std::filesystem::path& file) {
  std::ifstream in(file, std::ios::binary);
  if (!in) throw InputError(file.string(), "file", "expected a readable file");
  std::stringstream ss;
  ss << in.rdbuf();
  return parse_instrument(ss.str(), file.string(), file.stem().string());
}

const InstrumentSpec* InstrumentCatalogue::find(std::string_view name) const {
  for (const auto& s : items) {
    if (s.name == name) return &s;
  }
  return nullptr;
}

const InstrumentSpec& InstrumentCatalogue::get(std::string_view name) const {
  if (const auto* s = find(name)) return *s;
  std::string what = "expected one of: ";
  for (std::size_t i = 0; i < items.size(); ++i) {
    if (i) what += ", ";
    what += items[i].name;
  }
  what += "; got \"";
  what += name;
  what += "\"";
  throw InputError("instrument", "name", what);
}

InstrumentCatalogue load_catalogue(const std::filesystem::path& dir) {
  std::error_code ec;
  if (!std::filesystem::is_directory(dir, ec)) {
    throw InputError(dir.string(), "directory", "expected a folder of instrument files");
  }
  std::vector<std::filesystem::path> files;
  for (const auto& e : std::filesystem::directory_iterator(dir)) {
    if (e.is_regular_file() && e.path().extension() == ".json") files.push_back(e.path());
  }
  std::sort(files.begin(), files.end());
  InstrumentCatalogue cat;
  for (const auto& f : files) cat.items.push_back(load_instrument(f));
  // Names equal file stems, so they are unique within one folder.
  return cat;
}

std::filesystem::path default_catalogue_dir() {
  if (const char* env = std::getenv("VCSIM_INSTRUMENTS_DIR"); env && *env) return env;
  return VCSIM_DEFAULT_INSTRUMENTS_DIR;
}

}  // namespace vcsim
