// Vessel tree: the built-in patients against clinical dimensions and LPS orientation, the JSON
// format (round trip, data files, clear errors), lesion profiles and routes.
#include <gtest/gtest.h>

#include <fstream>
#include <numbers>
#include <sstream>

#include "anatomy_test_util.h"

namespace vcsim {
namespace {

using test::patient;
constexpr double mm = 1e-3;

const VesselSegment& seg(const VesselTree& t, const char* name) {
  const int i = t.find(name);
  EXPECT_GE(i, 0) << name;
  return t.segments[std::max(i, 0)];
}

TEST(AnatomyDefaultPatient, HasTheIssuesSegmentsAndIsValid) {
  const VesselTree& t = patient();
  EXPECT_NO_THROW(validate_tree(t, "default"));
  for (const char* n : {"right_common_femoral",
                        "right_external_iliac",
                        "right_common_iliac",
                        "abdominal_aorta",
                        "thoracic_aorta",
                        "aortic_arch",
                        "brachiocephalic",
                        "left_common_carotid",
                        "left_subclavian",
                        "ascending_aorta",
                        "aortic_root",
                        "left_coronary_sinus",
                        "right_coronary_sinus",
                        "noncoronary_sinus",
                        "left_main",
                        "lad",
                        "diagonal_1",
                        "diagonal_2",
                        "lcx",
                        "obtuse_marginal_1",
                        "obtuse_marginal_2",
                        "rca",
                        "posterior_descending",
                        "posterolateral"})
    EXPECT_GE(t.find(n), 0) << n;
  EXPECT_EQ(t.segments[t.access.segment].name, "right_common_femoral");
  ASSERT_EQ(t.lesions.size(), 1u);
  EXPECT_EQ(t.target.segment, t.lesions[0].segment);
}

// Diameter at the middle of a segment, mm.
double mid_diameter(const VesselSegment& s) {
  return 2e3 * radius_at(s, 0.5 * segment_length(s));
}

TEST(AnatomyDefaultPatient, DimensionsAreClinical) {
  // clinical.md "Vessel dimensions (adult)".
  const VesselTree& t = patient();
  const VesselSegment& root = seg(t, "aortic_root");
  const double sinus_extent =  // sinus lobes reach offset + radius from the root axis
      (seg(t, "left_coronary_sinus").points[1] - seg(t, "left_coronary_sinus").points[0]).norm() +
      seg(t, "left_coronary_sinus").radii[0];
  EXPECT_NEAR(2e3 * sinus_extent, 33.5, 3.5);   // root 30-37 mm
  EXPECT_NEAR(2e3 * root.radii.back(), 29, 2);  // sinotubular junction, below the root maximum
  EXPECT_NEAR(mid_diameter(seg(t, "ascending_aorta")), 32.5, 2.5);  // 30-35
  EXPECT_NEAR(mid_diameter(seg(t, "aortic_arch")), 27.5, 2.5);      // 25-30
  EXPECT_NEAR(mid_diameter(seg(t, "thoracic_aorta")), 25, 3);       // 22-28
  EXPECT_NEAR(mid_diameter(seg(t, "abdominal_aorta")), 21.5, 3.5);  // 18-25
  EXPECT_NEAR(mid_diameter(seg(t, "right_common_iliac")), 9, 1);
  EXPECT_NEAR(mid_diameter(seg(t, "right_external_iliac")), 7.5, 1);
  const VesselSegment& cfa = seg(t, "right_common_femoral");
  EXPECT_NEAR(mid_diameter(cfa), 6.9, 1.4);       // 6.9 +- 1.4
  EXPECT_NEAR(segment_length(cfa) / mm, 43, 16);  // 43 +- 16
  // Coronaries (Dodge 1992, right-dominant): mean +- SD.
  const int lm = t.find("left_main");
  const VesselSegment& lms = t.segments[lm];
  EXPECT_NEAR(2e3 * lms.radii.front(), 4.5, 0.5);
  EXPECT_NEAR((segment_length(lms) - ostium_distance(t, lm)) / mm, 10.5, 5.3);
  EXPECT_NEAR(2e3 * seg(t, "lad").radii.front(), 3.7, 0.4);
  EXPECT_NEAR(2e3 * seg(t, "lad").radii.back(), 1.9, 0.4);
  EXPECT_NEAR(2e3 * seg(t, "rca").radii.front(), 3.9, 0.6);
  EXPECT_NEAR(2e3 * seg(t, "lcx").radii.front(), 3.4, 0.5);
  // LAD-LCx angle 75 +- 23 degrees (tangents 5 mm into each).
  const Vec3 a = tangent_at(seg(t, "lad"), 5 * mm), b = tangent_at(seg(t, "lcx"), 5 * mm);
  EXPECT_NEAR(std::acos(a.dot(b)) * 180.0 / std::numbers::pi, 75, 23);
}

TEST(AnatomyDefaultPatient, CoordinatesAreLps) {
  const VesselTree& t = patient();
  const Vec3 valve = t.segments[0].points[0];
  const Vec3 arch_top =
      point_at(seg(t, "aortic_arch"), 0.5 * segment_length(seg(t, "aortic_arch")));
  EXPECT_GT(arch_top.z(), valve.z() + 60 * mm);  // head is +z
  const Vec3 groin = seg(t, "right_common_femoral").points.back();
  EXPECT_LT(groin.z(), valve.z() - 400 * mm);  // femoral far below
  EXPECT_LT(groin.x(), -50 * mm);              // patient's right is -x
  ASSERT_TRUE(t.heart);
  EXPECT_GT(t.heart->centre.x(), valve.x() + 20 * mm);  // heart to the patient's left
  EXPECT_GT(seg(t, "thoracic_aorta").points[20].y(), t.heart->centre.y() + 40 * mm);  // posterior
  EXPECT_GT(t.heart->axis.x(), 0.3);                                                  // apex left,
  EXPECT_LT(t.heart->axis.y(), -0.3);                                                 // anterior,
  EXPECT_LT(t.heart->axis.z(), -0.3);                                                 // inferior
  EXPECT_GT(seg(t, "left_subclavian").points.back().x(), 40 * mm);
  EXPECT_LT(seg(t, "brachiocephalic").points.back().x(), -10 * mm);
}

TEST(AnatomyDefaultPatient, CoronariesLieOnTheHeart) {
  const VesselTree& t = patient();
  const HeartModel& h = *t.heart;
  const Vec3 e2 = h.axis.cross(h.anterior);
  for (int i = 0; i < t.num_segments(); ++i) {
    const VesselSegment& s = t.segments[i];
    if (s.kind != VesselKind::kCoronary || s.name == "left_main" || s.name == "rca") continue;
    for (std::size_t k = 2; k < s.points.size(); ++k) {
      // Radial projection onto the ellipsoid: the gap must be about the vessel radius.
      const Vec3 d = s.points[k] - h.centre;
      const double g = std::sqrt(std::pow(d.dot(h.axis) / h.radii.x(), 2) +
                                 std::pow(d.dot(h.anterior) / h.radii.y(), 2) +
                                 std::pow(d.dot(e2) / h.radii.z(), 2));
      const double gap = (d - d / g).norm() * (g > 1 ? 1 : -1);
      EXPECT_GT(gap, 0.0) << s.name << " point " << k;
      EXPECT_LT(gap, s.radii[k] + 1.5 * mm) << s.name << " point " << k;
    }
  }
}

// Past its ostium no coronary bends tighter than 1.5 of its radii (the curvature radius through
// points 2 mm either side): tighter, the inner wall folds and a wire's tip is held in the fold.
// The LAD and LCx leaving their bifurcation come closest (1.8-2.2 radii). The RCA's lead from the
// right sinus, until 2026-11-28, doubled back to the groove at 1.2 radii.
TEST(AnatomyPatients, CoronariesHaveNoKinks) {
  for (const PatientVariant v :
       {PatientVariant::kRightDominant, PatientVariant::kLeftDominantTortuous}) {
    const VesselTree& t = patient(v);
    for (int i = 0; i < t.num_segments(); ++i) {
      const VesselSegment& s = t.segments[i];
      if (s.kind != VesselKind::kCoronary) continue;
      const double len = segment_length(s);
      for (double d = ostium_distance(t, i) + 0.5 * mm; d < len - 2 * mm; d += 0.5 * mm) {
        if (d < 2 * mm) continue;
        const Vec3 a = point_at(s, d - 2 * mm), b = point_at(s, d), c = point_at(s, d + 2 * mm);
        const double twice_area = (b - a).cross(c - a).norm();
        if (twice_area < 1e-15) continue;  // straight
        const double rc = (b - a).norm() * (c - b).norm() * (a - c).norm() / (2 * twice_area);
        EXPECT_GT(rc, 1.5 * radius_at(s, d)) << s.name << " at " << d / mm << " mm";
      }
    }
  }
}

TEST(AnatomyLeftDominant, DiffersWhereItShould) {
  const VesselTree &r = patient(), &l = patient(PatientVariant::kLeftDominantTortuous);
  EXPECT_NO_THROW(validate_tree(l, "left"));
  // The posterior descending artery comes from the circumflex; the RCA is small.
  EXPECT_EQ(l.segments[l.segments[l.find("posterior_descending")].parent].name, "lcx");
  EXPECT_LT(seg(l, "rca").radii.front(), seg(l, "lcx").radii.front());
  EXPECT_NEAR(2e3 * seg(l, "rca").radii.front(), 2.8, 0.5);  // Dodge left-dominant
  EXPECT_NEAR(2e3 * seg(l, "lcx").radii.front(), 4.2, 0.6);
  // Elongated, higher arch and a longer (tortuous) descending aorta.
  EXPECT_GT(segment_length(seg(l, "ascending_aorta")),
            segment_length(seg(r, "ascending_aorta")) + 10 * mm);
  EXPECT_GT(segment_length(seg(l, "thoracic_aorta")),
            segment_length(seg(r, "thoracic_aorta")) + 15 * mm);
  EXPECT_EQ(l.find("posterolateral"), -1);
}

TEST(AnatomyTree, OpenEndsAreTheVesselOutlets) {
  const VesselTree& t = patient();
  const auto ends = open_ends(t);
  EXPECT_EQ(ends.size(), 13u);
  for (const auto& e : ends) {
    const VesselSegment& s = t.segments[e.segment];
    EXPECT_FALSE(s.closed_end);
    EXPECT_NEAR(e.outward.norm(), 1.0, 1e-12);
    EXPECT_GT(e.outward.dot(s.points.back() - s.points[s.points.size() - 2]), 0.0);
    EXPECT_EQ(e.radius, s.radii.back());
  }
}

TEST(AnatomyTree, RouteRunsFromAccessToTarget) {
  const VesselTree& t = patient();
  const auto r = route(t, t.access, t.target, 2 * mm);
  ASSERT_GT(r.size(), 100u);
  EXPECT_LT((r.front() - point_at(t.segments[t.access.segment], t.access.distance)).norm(), 1e-9);
  EXPECT_LT((r.back() - point_at(t.segments[t.target.segment], t.target.distance)).norm(), 1e-9);
  double len = 0.0;
  for (std::size_t i = 1; i < r.size(); ++i) {
    EXPECT_LT((r[i] - r[i - 1]).norm(), 2.05 * mm);
    len += (r[i] - r[i - 1]).norm();
  }
  // Groin to coronary: roughly the femoral-to-root length plus the coronary run.
  EXPECT_GT(len, 600 * mm);
  EXPECT_LT(len, 1000 * mm);
}

TEST(AnatomyLesion, ProfileMatchesItsDefinition) {
  Lesion l;
  l.distance = 5 * mm;
  l.length = 10 * mm;
  l.diameter_reduction = 0.7;
  l.eccentricity = 0.5;
  const double r0 = 1.5 * mm;
  EXPECT_EQ(lesion_profile(l, 2 * mm, r0, 6.9 * mm).factor, 1.0);   // before
  EXPECT_EQ(lesion_profile(l, 2 * mm, r0, 17.1 * mm).factor, 1.0);  // after
  const LesionProfile throat = lesion_profile(l, 2 * mm, r0, 12 * mm);
  EXPECT_NEAR(throat.factor, 0.3, 1e-12);
  EXPECT_NEAR(throat.shift, 0.5 * 0.7 * r0, 1e-15);
  // The stenosed centreline follows.
  const VesselTree& t = patient();
  const VesselTree st = stenosed_tree(t);
  const Lesion& les = t.lesions[0];
  const double s_throat = ostium_distance(t, les.segment) + les.distance + 0.5 * les.length;
  const VesselSegment& h = t.segments[les.segment];
  const VesselSegment& s = st.segments[les.segment];
  EXPECT_NEAR(radius_at(s, s_throat) / radius_at(h, s_throat), 1.0 - les.diameter_reduction, 0.01);
  EXPECT_NEAR((point_at(s, s_throat) - point_at(h, s_throat)).norm(),
              les.eccentricity * les.diameter_reduction * radius_at(h, s_throat), 0.02 * mm);
  EXPECT_NO_THROW(validate_tree(st, "stenosed"));
}

void expect_same(const VesselTree& a, const VesselTree& b, double tol) {
  EXPECT_EQ(a.name, b.name);
  EXPECT_EQ(a.open_start, b.open_start);
  ASSERT_EQ(a.num_segments(), b.num_segments());
  for (int i = 0; i < a.num_segments(); ++i) {
    const auto &x = a.segments[i], &y = b.segments[i];
    EXPECT_EQ(x.name, y.name);
    EXPECT_EQ(x.kind, y.kind);
    EXPECT_EQ(x.parent, y.parent);
    EXPECT_EQ(x.closed_end, y.closed_end);
    ASSERT_EQ(x.points.size(), y.points.size());
    for (std::size_t k = 0; k < x.points.size(); ++k) {
      EXPECT_LT((x.points[k] - y.points[k]).norm(), tol);
      EXPECT_NEAR(x.radii[k], y.radii[k], tol);
    }
  }
  ASSERT_EQ(a.lesions.size(), b.lesions.size());
  for (std::size_t i = 0; i < a.lesions.size(); ++i) {
    EXPECT_EQ(a.lesions[i].segment, b.lesions[i].segment);
    EXPECT_NEAR(a.lesions[i].distance, b.lesions[i].distance, tol);
    EXPECT_NEAR(a.lesions[i].diameter_reduction, b.lesions[i].diameter_reduction, 1e-9);
    EXPECT_NEAR(a.lesions[i].length, b.lesions[i].length, tol);
    EXPECT_EQ(a.lesions[i].eccentricity, b.lesions[i].eccentricity);
    EXPECT_NEAR(a.lesions[i].angle, b.lesions[i].angle, 1e-6);  // degrees to 1e-4 in the file
  }
  EXPECT_EQ(a.access.segment, b.access.segment);
  EXPECT_NEAR(a.access.distance, b.access.distance, tol);
  EXPECT_EQ(a.target.segment, b.target.segment);
  EXPECT_NEAR(a.target.distance, b.target.distance, tol);
  ASSERT_EQ(a.heart.has_value(), b.heart.has_value());
  if (a.heart) {
    EXPECT_LT((a.heart->centre - b.heart->centre).norm(), tol);
    EXPECT_LT((a.heart->axis - b.heart->axis).norm(), 1e-4);
    EXPECT_LT((a.heart->anterior - b.heart->anterior).norm(), 1e-4);
    EXPECT_LT((a.heart->radii - b.heart->radii).norm(), tol);
  }
}

// The built-in patients exist only in code (default_patient.cpp); `vcsim anatomy export` writes
// them as files, which must load back as the same tree.
TEST(AnatomyJson, RoundTrips) {
  for (auto v : {PatientVariant::kRightDominant, PatientVariant::kLeftDominantTortuous}) {
    const VesselTree& t = patient(v);
    expect_same(t, parse_vessel_tree(vessel_tree_to_json(t), "round trip"), 1e-7);
  }
}

TEST(AnatomyJson, ExampleFileLoads) {
  const VesselTree ex =
      load_vessel_tree(std::string(VCSIM_ANATOMY_DATA) + "/bifurcation_example.json");
  EXPECT_EQ(ex.num_segments(), 2);
  EXPECT_NEAR(ex.segments[0].radii[3], 2 * mm, 1e-12);  // radius_mm applies to every point
  EXPECT_TRUE(ex.open_start);
}

std::string example() {
  std::ifstream f(std::string(VCSIM_ANATOMY_DATA) + "/bifurcation_example.json");
  std::stringstream ss;
  ss << f.rdbuf();
  return ss.str();
}

std::string replaced(std::string s, const std::string& from, const std::string& to) {
  const auto p = s.find(from);
  EXPECT_NE(p, std::string::npos) << from;
  if (p != std::string::npos) s.replace(p, from.size(), to);
  return s;
}

TEST(AnatomyJson, MalformedFilesGiveClearErrors) {
  const std::string ok = example();
  ASSERT_NO_THROW(parse_vessel_tree(ok, "ok.json"));
  struct Case {
    std::string text, field;
  };
  const std::vector<Case> cases = {
      {"{\"format\": ", "json"},
      {"[1, 2]", "json"},
      {replaced(ok, "\"vcsim-anatomy\"", "\"other\""), "format"},
      {replaced(ok, "\"version\": 1", "\"version\": 2"), "version"},
      {replaced(ok, "\"coordinates\": \"LPS\"", "\"coordinates\": \"RAS\""), "coordinates"},
      {replaced(ok, "\"open_start\"", "\"open_sart\""), "open_sart"},
      {replaced(ok, "\"name\": \"branch\"", "\"nam\": \"branch\""), "segments[1].nam"},
      {replaced(ok, "\"parent\": \"main\"", "\"parent\": \"mian\""), "segments[1].parent"},
      {replaced(ok, "\"name\": \"branch\"", "\"name\": \"main\""), "segments[1].name"},
      {replaced(ok, "[1.5, 1.5, 1.4, 1.3, 1.2]", "[1.5, 1.5, 1.4, 1.3]"), "segments[1].radii_mm"},
      {replaced(ok, "[1.5, 1.5, 1.4, 1.3, 1.2]", "[1.5, -1.5, 1.4, 1.3, 1.2]"),
       "segments[1].radii_mm[1]"},
      {replaced(ok, "[1.5, 1.5, 1.4, 1.3, 1.2]", "[1.5, \"x\", 1.4, 1.3, 1.2]"),
       "segments[1].radii_mm[1]"},
      {replaced(ok, "[3, 0, 35]", "[3, 0]"), "segments[1].points_mm[1]"},
      {replaced(ok, "[3, 0, 35]", "[0, 0, 30]"), "segments[1].points_mm[1]"},
      {replaced(ok, "[[0, 0, 30], [3, 0, 35]", "[[9, 0, 30], [3, 0, 35]"),
       "segments[1].points_mm[0]"},
      {replaced(ok, "\"radius_mm\": 2.0", "\"radius_mm\": 2.0, \"radii_mm\": [2, 2, 2, 2, 2, 2]"),
       "segments[0].radii_mm"},
      {replaced(ok, "\"kind\": \"artery\"", "\"kind\": \"vein\""), "segments[0].kind"},
      {replaced(ok, "\"diameter_reduction_percent\": 50", "\"diameter_reduction_percent\": 120"),
       "lesions[0].diameter_reduction_percent"},
      {replaced(ok, "\"length_mm\": 8", "\"length_mm\": 80"), "lesions[0].length_mm"},
      {replaced(ok, "{\"segment\": \"main\", \"distance_mm\": 20",
                "{\"segment\": \"left\", \"distance_mm\": 20"),
       "lesions[0].segment"},
      {replaced(ok, "\"distance_mm\": 15", "\"distance_mm\": 150"), "target.distance_mm"},
      {replaced(ok, "\"segments\": [", "\"segments\": [] , \"x\": ["), "x"},
  };
  for (const Case& c : cases) {
    try {
      parse_vessel_tree(c.text, "case.json");
      ADD_FAILURE() << "accepted; expected an error on " << c.field;
    } catch (const InputError& e) {
      EXPECT_EQ(e.source(), "case.json");
      EXPECT_EQ(e.field(), c.field) << e.what();
      EXPECT_EQ(std::string(e.what()).find('\n'), std::string::npos);  // one line
    }
  }
  try {
    load_vessel_tree("/nonexistent/anatomy.json");
    ADD_FAILURE();
  } catch (const InputError& e) {
    EXPECT_EQ(e.source(), "/nonexistent/anatomy.json");
  }
}

// Nesting 100,000 deep (which overflowed the stack), a number beyond a double and a repeated key
// are input errors naming the file, never a crash or a library's message.
TEST(AnatomyJson, HostileJsonIsAnInputError) {
  const std::string ok = example();
  const std::string deep = std::string(100000, '[') + std::string(100000, ']');
  const std::vector<std::pair<std::string, std::string>> cases = {
      {deep, "json"},
      {replaced(ok, "[[0, 0, 30], [3, 0, 35]", std::string("[") + deep + ", [3, 0, 35]"), "json"},
      {replaced(ok, "\"radius_mm\": 2.0", "\"radius_mm\": 2e999"), "json"},
      {replaced(ok, "\"version\": 1,", "\"version\": 1, \"version\": 1,"), "version"},
      {replaced(ok, "\"radius_mm\": 2.0", "\"radius_mm\": 2.0, \"radius_mm\": 3.0"),
       "segments[0].radius_mm"},
  };
  for (const auto& [text, field] : cases) {
    try {
      parse_vessel_tree(text, "case.json");
      ADD_FAILURE() << "accepted; expected an error on " << field;
    } catch (const InputError& e) {
      EXPECT_EQ(e.source(), "case.json");
      EXPECT_EQ(e.field(), field) << e.what();
    }
  }
}

}  // namespace
}  // namespace vcsim
