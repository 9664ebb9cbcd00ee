// `vcsim instruments list|show NAME`: the catalogue in data/instruments (Markdown or --json).
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>

#include "commands.h"
#include "vcsim/instruments.h"
#include "vcsim/units.h"

namespace vcsim::app {

namespace {

std::string fmt(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.4g", v);
  return buf;
}

constexpr double kPerCm = 100.0;  // 1/cm in 1/m

// A value converted back to the file's unit, rounded to 12 significant digits so that 18 mm
// read as 0.018 m prints as 18, not 18.000000000000004.
double in_unit(double si, double unit) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.12g", si / unit);
  return std::strtod(buf, nullptr);
}

// The file's units (mm, GPa, deg, 1/cm), so that the output reads like the catalogue file.
nlohmann::json to_json(const InstrumentSpec& s, const Discretisation& disc) {
  nlohmann::json sections = nlohmann::json::array();
  for (const auto& t : s.tip_shape) {
    if (t.kind == TipSection::Kind::kStraight) {
      sections.push_back({{"straight_mm", t.length * 1e3}});
    } else {
      sections.push_back({{"arc",
                           {{"radius_mm", t.radius * 1e3},
                            {"angle_deg", t.angle * kDegPerRad},
                            {"plane_deg", t.plane * kDegPerRad}}}});
    }
  }
  const SegmentPlan plan = plan_segments(s.length, disc);
  nlohmann::json j = {{"name", s.name},
                      {"description", s.description},
                      {"kind", to_string(s.kind)},
                      {"file", s.source},
                      {"length_mm", s.length * 1e3},
                      {"od_mm", s.outer_diameter * 1e3},
                      {"id_mm", s.inner_diameter * 1e3},
                      {"youngs_modulus_gpa", s.youngs_modulus * 1e-9},
                      {"tip_length_mm", s.tip_length * 1e3},
                      {"tip_modulus_ratio", s.tip_modulus_ratio},
                      {"core_taper_mm", s.core_taper_length * 1e3},
                      {"poisson", s.poisson},
                      {"density_kg_m3", s.density},
                      {"tip_sections", sections},
                      {"friction",
                       {{"vessel_static", s.friction.vessel_static},
                        {"vessel_dynamic", s.friction.vessel_dynamic},
                        {"lumen", s.friction.lumen}}},
                      {"radiopacity",
                       {{"material", s.radiopacity.material},
                        {"attenuation_60kev_per_cm", s.radiopacity.attenuation_60kev * 1e-2},
                        {"attenuation_80kev_per_cm", s.radiopacity.attenuation_80kev * 1e-2},
                        {"coil_length_mm", s.radiopacity.coil_length * 1e3},
                        {"markers_mm_from_tip",
                         [&] {
                           nlohmann::json m = nlohmann::json::array();
                           for (double d : s.radiopacity.markers) m.push_back(d * 1e3);
                           return m;
                         }()}}},
                      {"discretisation",
                       {{"nodes", plan.segments + 1},
                        {"grading", plan.grading},
                        {"distal_segment_mm", plan.distal * 1e3},
                        {"proximal_segment_mm", plan.proximal * 1e3}}}};
  // The shaft's torsional rigidity (N m^2), the braid's included, which the rod is built with.
  j["torsional_rigidity_n_m2"] = s.torsional_rigidity();
  if (s.braid) {
    j["braid"] = {{"wires", s.braid->wires},
                  {"wire_width_mm", in_unit(s.braid->wire_width, kMm)},
                  {"wire_thickness_mm", in_unit(s.braid->wire_thickness, kMm)},
                  {"angle_deg", in_unit(s.braid->angle, kDeg)},
                  {"modulus_gpa", s.braid->modulus * 1e-9}};
  }
  if (s.taper_length > 0.0) {
    j["tip_taper_mm"] = s.taper_length * 1e3;
    j["tip_entry_profile_mm"] = s.entry_profile * 1e3;
  }
  if (s.balloon) {
    const BalloonSpec& b = *s.balloon;
    nlohmann::json chart = nlohmann::json::array();
    for (std::size_t i = 0; i < b.chart_pressure.size(); ++i) {
      chart.push_back({in_unit(b.chart_pressure[i], kAtm), in_unit(b.chart_diameter[i], kMm)});
    }
    j["balloon"] = {
        {"compliance", b.compliance == BalloonSpec::Compliance::kSemiCompliant ? "semi-compliant"
                                                                               : "non-compliant"},
        {"nominal_diameter_mm", in_unit(b.nominal_diameter, kMm)},
        {"length_mm", in_unit(b.length, kMm)},
        {"distal_offset_mm", in_unit(b.distal_offset, kMm)},
        {"nominal_pressure_atm", in_unit(b.nominal_pressure, kAtm)},
        {"rated_burst_pressure_atm", in_unit(b.rated_burst_pressure, kAtm)},
        {"crossing_profile_mm", in_unit(b.crossing_profile, kMm)},
        {"lengthening_at_rbp_mm", in_unit(b.lengthening, kMm)},
        {"chart", chart}};
  }
  if (s.stent) {
    const StentSpec& t = *s.stent;
    j["stent"] = {{"nominal_diameter_mm", in_unit(t.nominal_diameter, kMm)},
                  {"length_mm", in_unit(t.length, kMm)},
                  {"strut_thickness_um", in_unit(t.strut_thickness, kUm)},
                  {"material", t.material},
                  {"attenuation_60kev_per_cm", in_unit(t.attenuation_60kev, kPerCm)},
                  {"attenuation_80kev_per_cm", in_unit(t.attenuation_80kev, kPerCm)},
                  {"metal_coverage", t.metal_coverage},
                  {"acute_recoil", t.acute_recoil},
                  {"foreshortening", t.foreshortening},
                  {"crimped_profile_mm", in_unit(t.crimped_profile, kMm)}};
  }
  return j;
}

// The balloon's and stent's fields as Markdown: the compliance chart as a table, with the working
// length each pressure gives.
void print_balloon_and_stent(const InstrumentSpec& s, const nlohmann::json& j) {
  if (s.balloon) {
    const BalloonSpec& b = *s.balloon;
    std::cout << "\n## Balloon\n\n";
    for (const auto& [k, v] : j["balloon"].items()) {
      if (k != "chart") std::cout << "- " << k << ": " << v.dump() << "\n";
    }
    std::cout << "\n| pressure (atm) | diameter (mm) | working length (mm) |\n|---|---|---|\n";
    std::cout << "| 0 | " << fmt(b.diameter_at(0.0) * 1e3) << " (folded) | "
              << fmt(b.length_at(0.0) * 1e3) << " |\n";
    for (std::size_t i = 0; i < b.chart_pressure.size(); ++i) {
      const double p = b.chart_pressure[i];
      std::cout << "| " << fmt(p / kAtm) << " | " << fmt(b.chart_diameter[i] * 1e3) << " | "
                << fmt(b.length_at(p) * 1e3) << " |\n";
    }
  }
  if (s.stent) {
    std::cout << "\n## Stent\n\n";
    for (const auto& [k, v] : j["stent"].items())
      std::cout << "- " << k << ": " << v.dump() << "\n";
  }
}

struct Args {
  std::string dir;
  std::string name;
  bool json = false;
  Discretisation disc;
  double tip_segment_mm = 1.0;
};

InstrumentCatalogue load(const Args& a) {
  return load_catalogue(a.dir.empty() ? default_catalogue_dir() : std::filesystem::path(a.dir));
}

Discretisation disc_of(const Args& a) {
  Discretisation d = a.disc;
  d.tip_segment = a.tip_segment_mm * 1e-3;
  d.validate("instruments");
  return d;
}

void add_common(CLI::App* sub, Args& a) {
  sub->add_option("--dir", a.dir, "Catalogue folder (default: $VCSIM_INSTRUMENTS_DIR or data/)");
  sub->add_flag("--json", a.json, "Print JSON instead of Markdown");
  sub->add_option("--max-nodes", a.disc.max_nodes, "Largest number of rod nodes per instrument");
  sub->add_option("--tip-segment-mm", a.tip_segment_mm, "Distal segment length (mm)");
}

void install(CLI::App& app, int& status) {
  auto a = std::make_shared<Args>();
  auto* grp = app.add_subcommand("instruments", "The instrument catalogue (data/instruments)");
  grp->require_subcommand(1);

  auto* list = grp->add_subcommand("list", "List the catalogue's instruments");
  add_common(list, *a);
  list->callback([a, &status] {
    const Discretisation disc = disc_of(*a);
    const auto cat = load(*a);
    if (a->json) {
      nlohmann::json arr = nlohmann::json::array();
      for (const auto& s : cat.items) arr.push_back(to_json(s, disc));
      std::cout << arr.dump(2) << "\n";
    } else {
      std::cout << "| name | kind | length (mm) | OD (mm) | ID (mm) | E (GPa) | nodes | "
                   "description |\n|---|---|---|---|---|---|---|---|\n";
      for (const auto& s : cat.items) {
        const SegmentPlan p = plan_segments(s.length, disc);
        std::cout << "| " << s.name << " | " << to_string(s.kind) << " | " << fmt(s.length * 1e3)
                  << " | " << fmt(s.outer_diameter * 1e3) << " | " << fmt(s.inner_diameter * 1e3)
                  << " | " << fmt(s.youngs_modulus * 1e-9) << " | " << p.segments + 1 << " | "
                  << s.description << " |\n";
      }
    }
    status = 0;
  });

  auto* show = grp->add_subcommand("show", "Show one instrument and its rod discretisation");
  show->add_option("name", a->name, "Instrument name (see `vcsim instruments list`)")->required();
  add_common(show, *a);
  show->callback([a, &status] {
    const Discretisation disc = disc_of(*a);
    const auto cat = load(*a);
    const InstrumentSpec& s = cat.get(a->name);
    const RodDef def = to_rod_def(s, disc);  // proves the entry builds a valid rod definition
    const nlohmann::json j = to_json(s, disc);
    if (a->json) {
      std::cout << j.dump(2) << "\n";
    } else {
      std::cout << "# " << s.name << "\n\n" << s.description << "\n\n";
      for (const auto& [k, v] : j.items()) {
        if (k == "name" || k == "description" || k == "balloon" || k == "stent") continue;
        std::cout << "- " << k << ": " << v.dump() << "\n";
      }
      std::cout << "- rod: " << def.segments << " segments, grading " << fmt(def.grading) << "\n";
      print_balloon_and_stent(s, j);
    }
    status = 0;
  });
}

const int kRegistered = register_command(30, install);

}  // namespace

}  // namespace vcsim::app
