// vcsim instruments: the catalogue of guidewires and catheters (data/instruments/*.json) and the
// mapping of a catalogue entry to a rod definition with a bounded number of nodes.
//
// Files carry units in their key names (length_mm, od_in, youngs_modulus_gpa); specs hold SI
// (m, Pa, kg/m^3, rad). docs/instruments.md lists every field and the source of every value.
#pragma once

#include "vcsim/core.h"
#include "vcsim/rod.h"

#include <filesystem>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace vcsim {

// kBalloon: a balloon dilatation catheter; kStent: a stent system (a stent crimped on the balloon
// of its delivery catheter). Both ride on a coronary wire (rapid exchange) inside the guide.
enum class InstrumentKind { kGuidewire, kCatheter, kBalloon, kStent };
const char* to_string(InstrumentKind k);

// The balloon of a balloon catheter or stent system, from the manufacturer's compliance chart.
struct BalloonSpec {
  enum class Compliance { kSemiCompliant, kNonCompliant };
  Compliance compliance = Compliance::kSemiCompliant;
  double nominal_diameter = 3.0e-3;  // (m) at nominal pressure, the labelled size
  double length = 15e-3;             // working length (m) at nominal pressure
  double distal_offset = 4e-3;       // from the catheter's tip to the balloon's distal end (m)
  double nominal_pressure = 8 * 101325.0;       // (Pa)
  double rated_burst_pressure = 14 * 101325.0;  // (Pa)
  double crossing_profile = 0.9e-3;             // outer diameter over the folded balloon (m)
  double lengthening = 1.0e-3;  // working length gained from nominal to rated burst (m)
  // The compliance chart: free diameter (m) at each gauge pressure (Pa), pressures strictly
  // increasing from at most the nominal to at least the rated burst pressure, diameters
  // non-decreasing; the nominal pressure gives the nominal diameter.
  std::vector<double> chart_pressure;
  std::vector<double> chart_diameter;

  // Free (unconstrained) diameter at gauge pressure p (Pa): linear between the chart's entries,
  // held at the last entry above it; below the first entry, linear from the crossing profile at 0
  // (the folded balloon unfolds) to the first entry.
  double diameter_at(double pressure) const;
  // Working length at p: the nominal length, growing linearly by `lengthening` from nominal to
  // rated burst pressure (held outside that range).
  double length_at(double pressure) const;
};

// A balloon-expandable stent crimped on its delivery balloon.
struct StentSpec {
  double nominal_diameter = 3.0e-3;  // (m) expanded at the balloon's nominal pressure
  double length = 15e-3;             // (m) expanded
  double strut_thickness = 81e-6;    // (m)
  std::string material;              // e.g. "cobalt-chromium"
  double attenuation_60kev = 0.0;    // linear attenuation of the strut material (1/m)
  double attenuation_80kev = 0.0;    // (1/m)
  double metal_coverage = 0.15;      // fraction of the stent's surface that is strut (0, 1)
  double acute_recoil = 0.05;        // fraction of the expanded diameter lost on deflation
  double foreshortening = 0.0;       // fraction of the crimped length lost on expansion
  double crimped_profile = 1.0e-3;   // outer diameter of the crimped stent on its balloon (m)
};

// Coulomb coefficients (dimensionless).
struct InstrumentFriction {
  double vessel_static = 0.1;   // against the vessel wall, sticking
  double vessel_dynamic = 0.1;  // against the vessel wall, sliding (<= static)
  double lumen = 0.04;          // inside another instrument's lumen (or around a wire)
};

// What the fluoroscopy renderer needs to draw the instrument.
struct InstrumentRadiopacity {
  std::string material;                 // shaft material name, e.g. "nitinol"
  double attenuation_60kev = 0.0;       // linear attenuation of the shaft material (1/m)
  double attenuation_80kev = 0.0;       // (1/m)
  double coil_length = 0.0;             // radiopaque distal coil (m), 0 for none
  double coil_attenuation_60kev = 0.0;  // (1/m)
  double coil_attenuation_80kev = 0.0;  // (1/m)
  std::vector<double> markers;          // marker band positions, distance from the distal tip (m)
};

// A braided catheter's reinforcing braid (stainless flat wire embedded in the wall): it gives the
// shaft its torque response, which a polymer tube of the same flexural modulus lacks (a JR4
// turned at the hand in the aortic root hardly turned at its tip without it; docs/
// instruments.md, "Braid"). Only the torsional rigidity is taken from it: the entry's Young's
// modulus is already the whole section's, braid included.
struct BraidSpec {
  int wires = 16;                    // carriers, both helix directions together
  double wire_width = 0.075e-3;      // (m) of a flat wire
  double wire_thickness = 0.025e-3;  // (m)
  double angle = 1.0472;             // helix angle to the shaft's axis (rad)
  double modulus = 193e9;            // Young's modulus of the wire (Pa)
};

// One catalogue entry, in SI.
struct InstrumentSpec {
  std::string name;         // unique, equal to the file stem
  std::string description;  // one line for humans
  std::string source;       // file it was read from (for later error messages)
  InstrumentKind kind = InstrumentKind::kGuidewire;
  double length = 1.5;               // (m)
  double outer_diameter = 0.889e-3;  // (m)
  double inner_diameter = 0.0;       // (m), 0 for a solid wire
  double youngs_modulus = 1e10;      // whole-section flexural modulus of the shaft (Pa)
  double tip_length = 0.0;           // soft distal length (m)
  double tip_modulus_ratio = 1.0;    // E_tip / E_shaft in (0, 1]
  double core_taper_length = 0.0;    // a wire's core ground down over this, proximal to the tip (m)
  double taper_length = 0.0;         // distal taper to the entry profile (m), 0 for none
  double entry_profile = 0.0;        // outer diameter at the very tip when tapered (m)
  double poisson = 0.3;
  std::optional<BraidSpec> braid;     // catheters: torsion from the braid as well as the wall
  double density = 6450.0;            // (kg/m^3)
  std::vector<TipSection> tip_shape;  // rest shape of the distal end, proximal to distal
  InstrumentFriction friction;
  InstrumentRadiopacity radiopacity;
  std::optional<BalloonSpec> balloon;  // kBalloon and kStent (the delivery balloon)
  std::optional<StentSpec> stent;      // kStent

  // Length of the shaped distal part (sum of the tip sections) (m).
  double shaped_length() const;
  // Torsional rigidity G J of the shaft (N m^2): the wall's, E / (2 (1 + poisson)) times the
  // annulus' polar moment, plus the braid's by netting analysis (each wire carries only its
  // axial load): n E_w A_w R^2 sin^2(a) cos(a), R the wall's mean radius.
  double torsional_rigidity() const;
  // Polar moment of the shaft's annulus, pi (ro^4 - ri^4) / 2 (m^4).
  double polar_moment() const;
};

// Parses one catalogue file's text. `source` names it in errors ("data/instruments/jl4.json");
// the entry's "name" must equal `expected_name` unless that is empty. Throws InputError naming
// the source and the field (e.g. "tip_sections[2].arc.radius_mm").
InstrumentSpec parse_instrument(std::string_view json_text, const std::string& source,
                                const std::string& expected_name = "");
// Reads and parses one file; the entry's name must equal the file stem.
InstrumentSpec load_instrument(const std::filesystem::path& file);

// Every *.json in a folder, sorted by name.
struct InstrumentCatalogue {
  std::vector<InstrumentSpec> items;
  const InstrumentSpec* find(std::string_view name) const;
  // Throws InputError("instrument", name, "expected one of ...") when absent.
  const InstrumentSpec& get(std::string_view name) const;
};
InstrumentCatalogue load_catalogue(const std::filesystem::path& dir);
// $VCSIM_INSTRUMENTS_DIR if set, else the source tree's data/instruments.
std::filesystem::path default_catalogue_dir();

// How a clinical length maps to rod segments: a geometric grading (RodDef::grading) that keeps
// the distal segments near `tip_segment` and the node count at most `max_nodes`. The shaft away
// from the tip gets coarser, where bending is gentle and the catheter or vessel guides it.
struct Discretisation {
  int max_nodes = 512;
  double tip_segment = 1.0e-3;  // target length of the most distal segment (m)
  int min_segments = 8;

  void validate(const std::string& source = "discretisation") const;
};

struct SegmentPlan {
  int segments = 0;       // edges (nodes = segments + 1)
  double grading = 1.0;   // distal / proximal segment length, as in RodDef
  double distal = 0.0;    // most distal segment length (m)
  double proximal = 0.0;  // most proximal segment length (m)
};

// Segments and grading for a rod of `length` (m). Uniform when length / tip_segment segments
// fit in max_nodes; otherwise max_nodes - 1 segments graded geometrically so that the distal
// one is tip_segment long.
SegmentPlan plan_segments(double length, const Discretisation& disc);

// The rod definition of a catalogue entry: geometry, materials, soft tip and tip shape, with
// segments from plan_segments. Pose and boundaries keep RodDef's defaults (clamped base).
RodDef to_rod_def(const InstrumentSpec& spec, const Discretisation& disc = {});

}  // namespace vcsim
