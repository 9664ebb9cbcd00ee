// The anatomy JSON format (docs/anatomy.md): millimetres and degrees in key names, converted to
// SI at load; unknown keys are refused so that a typo is not silently ignored.
#include <cmath>
#include <fstream>
#include <sstream>

#include "field.h"
#include "json_fields.h"
#include "vcsim/anatomy.h"
#include "vcsim/units.h"

namespace vcsim {

namespace {

using internal::index_path;
using internal::Json;
using internal::JsonFields;

Vec3 vec3(const Json& j, const JsonFields& f, const std::string& path, double scale) {
  if (!j.is_array() || j.size() != 3) throw InputError(f.source(), path, "expected [x, y, z]");
  return Vec3(f.as_number(j[0], index_path(path, 0)), f.as_number(j[1], index_path(path, 1)),
              f.as_number(j[2], index_path(path, 2))) *
         scale;
}

VesselKind kind_from(const std::string& s, const std::string& src, const std::string& f) {
  for (auto k :
       {VesselKind::kAorta, VesselKind::kArtery, VesselKind::kCoronary, VesselKind::kSinus})
    if (to_string(k) == s) return k;
  throw InputError(src, f, "expected aorta, artery, coronary or sinus, got '" + s + "'");
}

TreeLocation location(const Json& j, const VesselTree& t, const std::string& src,
                      const std::string& path) {
  if (!j.is_object()) throw InputError(src, path, "expected an object {segment, distance_mm}");
  JsonFields f(j, src, path);
  f.keys({"segment", "distance_mm"});
  TreeLocation loc;
  const std::string name = f.string("segment");
  loc.segment = t.find(name);
  if (loc.segment < 0) f.fail("segment", "no segment named '" + name + "'");
  loc.distance = f.number("distance_mm") * kMm;
  return loc;
}

// Numbers rounded to 0.1 um in millimetre files keep them short and exact enough.
double mm(double v) {
  return std::round(v / kMm * 1e4) / 1e4;
}

}  // namespace

VesselTree parse_vessel_tree(std::string_view json_text, const std::string& src) {
  const Json j = internal::parse_json_text(json_text, src);
  if (!j.is_object()) throw InputError(src, "json", "expected an object at the top level");
  JsonFields f(j, src, "");
  f.keys({"format", "version", "name", "coordinates", "open_start", "segments", "lesions",
          "access", "target", "heart"});
  if (f.string("format") != "vcsim-anatomy") f.fail("format", "expected \"vcsim-anatomy\"");
  if (f.number("version") != 1.0) f.fail("version", "expected 1");
  if (f.string_or("coordinates", "LPS") != "LPS")
    f.fail("coordinates", "expected \"LPS\" (DICOM patient coordinates)");
  VesselTree t;
  t.name = f.string_or("name", "unnamed");
  t.open_start = f.boolean_or("open_start", t.open_start);
  const Json& segs = f.array("segments");
  if (segs.empty()) f.fail("segments", "expected a non-empty array");
  for (std::size_t i = 0; i < segs.size(); ++i) {
    JsonFields s(segs[i], src, index_path("segments", i));
    s.keys({"name", "kind", "parent", "points_mm", "radii_mm", "radius_mm", "closed_end"});
    VesselSegment seg;
    seg.name = s.string("name");
    if (t.find(seg.name) >= 0)
      s.fail("name", "expected a unique name, '" + seg.name + "' repeats");
    if (s.has("kind")) seg.kind = kind_from(s.string("kind"), src, s.field("kind"));
    if (const Json* p = s.get("parent"); p && !p->is_null()) {
      const std::string name = s.as_string(*p, s.field("parent"));
      seg.parent = t.find(name);
      if (seg.parent < 0)
        s.fail("parent", "expected the name of an earlier segment, got '" + name + "'");
    }
    const Json& pts = s.require("points_mm");
    if (!pts.is_array()) s.fail("points_mm", "expected an array of [x, y, z]");
    for (std::size_t k = 0; k < pts.size(); ++k)
      seg.points.push_back(vec3(pts[k], s, index_path(s.field("points_mm"), k), kMm));
    if (s.has("radii_mm") == s.has("radius_mm"))
      s.fail("radii_mm", "expected either radii_mm (one per point) or radius_mm");
    if (s.has("radius_mm")) {
      seg.radii.assign(seg.points.size(), s.number("radius_mm") * kMm);
    } else {
      const Json& r = s.require("radii_mm");
      if (!r.is_array()) s.fail("radii_mm", "expected an array of numbers");
      for (std::size_t k = 0; k < r.size(); ++k)
        seg.radii.push_back(s.as_number(r[k], index_path(s.field("radii_mm"), k)) * kMm);
    }
    seg.closed_end = s.boolean_or("closed_end", seg.closed_end);
    t.segments.push_back(std::move(seg));
  }
  if (f.has("lesions")) {
    const Json& ls = f.array("lesions");
    for (std::size_t i = 0; i < ls.size(); ++i) {
      JsonFields l(ls[i], src, index_path("lesions", i));
      l.keys({"segment", "distance_mm", "length_mm", "diameter_reduction_percent", "eccentricity",
              "angle_deg"});
      Lesion les;
      const std::string name = l.string("segment");
      les.segment = t.find(name);
      if (les.segment < 0) l.fail("segment", "no segment named '" + name + "'");
      les.distance = l.number("distance_mm") * kMm;
      les.length = l.number("length_mm") * kMm;
      les.diameter_reduction = l.number("diameter_reduction_percent") / 100.0;
      if (l.has("eccentricity")) les.eccentricity = l.number("eccentricity");
      if (l.has("angle_deg")) les.angle = l.number("angle_deg") * kDeg;
      t.lesions.push_back(les);
    }
  }
  const Json* access = f.get("access");
  t.access = access ? location(*access, t, src, "access") : TreeLocation{0, 0.0};
  if (const Json* target = f.get("target")) {
    t.target = location(*target, t, src, "target");
  } else {
    t.target.segment = t.num_segments() - 1;
    t.target.distance = segment_length(t.segments.back());
  }
  if (const Json* heart = f.get("heart")) {
    JsonFields h(*heart, src, "heart");
    h.keys({"centre_mm", "axis", "anterior", "radii_mm"});
    HeartModel hm;
    hm.centre = vec3(h.require("centre_mm"), h, h.field("centre_mm"), kMm);
    hm.axis = vec3(h.require("axis"), h, h.field("axis"), 1.0);
    Vec3 ant = vec3(h.require("anterior"), h, h.field("anterior"), 1.0);
    hm.radii = vec3(h.require("radii_mm"), h, h.field("radii_mm"), kMm);
    if (hm.axis.norm() < 1e-9) h.fail("axis", "expected a non-zero vector");
    hm.axis.normalize();
    ant -= ant.dot(hm.axis) * hm.axis;
    if (ant.norm() < 1e-9) h.fail("anterior", "expected a vector not parallel to the axis");
    hm.anterior = ant.normalized();
    t.heart = hm;
  }
  validate_tree(t, src);
  return t;
}

VesselTree load_vessel_tree(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  if (!f) throw InputError(path, "file", "expected a readable anatomy JSON file");
  std::stringstream ss;
  ss << f.rdbuf();
  return parse_vessel_tree(ss.str(), path);
}

std::string vessel_tree_to_json(const VesselTree& t) {
  // Written by hand so that each point sits on one line; scalars through nlohmann for escaping.
  std::ostringstream os;
  auto v3 = [&](const Vec3& p, double scale) {
    os << '[' << Json(std::round(p.x() / scale * 1e4) / 1e4).dump() << ", "
       << Json(std::round(p.y() / scale * 1e4) / 1e4).dump() << ", "
       << Json(std::round(p.z() / scale * 1e4) / 1e4).dump() << ']';
  };
  os << "{\n  \"format\": \"vcsim-anatomy\",\n  \"version\": 1,\n  \"name\": "
     << Json(t.name).dump()
     << ",\n  \"coordinates\": \"LPS\",\n  \"open_start\": " << (t.open_start ? "true" : "false")
     << ",\n";
  auto loc = [&](const char* key, const TreeLocation& l) {
    os << "  \"" << key << "\": {\"segment\": " << Json(t.segments[l.segment].name).dump()
       << ", \"distance_mm\": " << Json(mm(l.distance)).dump() << "},\n";
  };
  loc("access", t.access);
  loc("target", t.target);
  if (t.heart) {
    const HeartModel& h = *t.heart;
    os << "  \"heart\": {\"centre_mm\": ";
    v3(h.centre, kMm);
    os << ", \"axis\": ";
    v3(h.axis, 1.0);
    os << ", \"anterior\": ";
    v3(h.anterior, 1.0);
    os << ", \"radii_mm\": ";
    v3(h.radii, kMm);
    os << "},\n";
  }
  os << "  \"lesions\": [";
  for (std::size_t i = 0; i < t.lesions.size(); ++i) {
    const Lesion& l = t.lesions[i];
    os << (i ? ",\n" : "\n") << "    {\"segment\": " << Json(t.segments[l.segment].name).dump()
       << ", \"distance_mm\": " << Json(mm(l.distance)).dump()
       << ", \"length_mm\": " << Json(mm(l.length)).dump() << ", \"diameter_reduction_percent\": "
       << Json(std::round(l.diameter_reduction * 1e6) / 1e4).dump()
       << ", \"eccentricity\": " << Json(l.eccentricity).dump()
       << ", \"angle_deg\": " << Json(std::round(l.angle / kDeg * 1e4) / 1e4).dump() << "}";
  }
  os << (t.lesions.empty() ? "" : "\n  ") << "],\n  \"segments\": [";
  for (std::size_t i = 0; i < t.segments.size(); ++i) {
    const VesselSegment& s = t.segments[i];
    os << (i ? ",\n" : "\n") << "    {\"name\": " << Json(s.name).dump() << ", \"kind\": \""
       << to_string(s.kind) << "\", \"parent\": "
       << (s.parent < 0 ? std::string("null") : Json(t.segments[s.parent].name).dump())
       << ", \"closed_end\": " << (s.closed_end ? "true" : "false") << ",\n     \"points_mm\": [";
    for (std::size_t k = 0; k < s.points.size(); ++k) {
      os << (k ? ",\n       " : "\n       ");
      v3(s.points[k], kMm);
    }
    os << "],\n     \"radii_mm\": [";
    for (std::size_t k = 0; k < s.radii.size(); ++k)
      os << (k ? (k % 10 ? ", " : ",\n       ") : "") << Json(mm(s.radii[k])).dump();
    os << "]}";
  }
  os << "\n  ]\n}\n";
  return os.str();
}

void save_vessel_tree(const VesselTree& t, const std::string& path) {
  std::ofstream f(path, std::ios::binary);
  if (!f) throw InputError(path, "file", "expected a writable path");
  f << vessel_tree_to_json(t);
  if (!f) throw InputError(path, "file", "write failed");
}

}  // namespace vcsim
