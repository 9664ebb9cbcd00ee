// The anatomy JSON format (docs/anatomy.md): millimetres and degrees in key names, converted to
// SI at load; unknown keys are refused so that a typo is not silently ignored.
#include <cmath>
#include <fstream>
#include <initializer_list>
#include <nlohmann/json.hpp>
#include <sstream>

#include "field.h"
#include "vcsim/anatomy.h"
#include "vcsim/units.h"

namespace vcsim {

namespace {

using nlohmann::json;

std::string at(const std::string& base, std::size_t i) {
  std::string s = base;
  s += '[';
  s += std::to_string(i);
  s += ']';
  return s;
}

void only_keys(const json& j, std::initializer_list<const char*> keys, const std::string& src,
               const std::string& field) {
  for (auto it = j.begin(); it != j.end(); ++it) {
    bool ok = false;
    for (const char* k : keys) ok = ok || it.key() == k;
    if (!ok) {
      std::string list;
      for (const char* k : keys) {
        if (!list.empty()) list += ", ";
        list += k;
      }
      std::string f = field.empty() ? it.key() : field + "." + it.key();
      throw InputError(src, f, "unknown key; expected one of " + list);
    }
  }
}

const json& need(const json& j, const char* key, const std::string& src, const std::string& f) {
  if (!j.contains(key)) throw InputError(src, f.empty() ? key : f + "." + key, "missing");
  return j.at(key);
}

double number(const json& j, const std::string& src, const std::string& f) {
  if (!j.is_number()) throw InputError(src, f, "expected a number");
  return require_finite(j.get<double>(), src, f);
}

std::string text(const json& j, const std::string& src, const std::string& f) {
  if (!j.is_string()) throw InputError(src, f, "expected a string");
  return j.get<std::string>();
}

Vec3 vec3(const json& j, const std::string& src, const std::string& f, double scale) {
  if (!j.is_array() || j.size() != 3) throw InputError(src, f, "expected [x, y, z]");
  return Vec3(number(j[0], src, at(f, 0)), number(j[1], src, at(f, 1)),
              number(j[2], src, at(f, 2))) *
         scale;
}

VesselKind kind_from(const std::string& s, const std::string& src, const std::string& f) {
  for (auto k :
       {VesselKind::kAorta, VesselKind::kArtery, VesselKind::kCoronary, VesselKind::kSinus})
    if (to_string(k) == s) return k;
  throw InputError(src, f, "expected aorta, artery, coronary or sinus, got '" + s + "'");
}

TreeLocation location(const json& j, const VesselTree& t, const std::string& src,
                      const std::string& f) {
  if (!j.is_object()) throw InputError(src, f, "expected an object {segment, distance_mm}");
  only_keys(j, {"segment", "distance_mm"}, src, f);
  TreeLocation loc;
  const std::string name = text(need(j, "segment", src, f), src, f + ".segment");
  loc.segment = t.find(name);
  if (loc.segment < 0) throw InputError(src, f + ".segment", "no segment named '" + name + "'");
  loc.distance = number(need(j, "distance_mm", src, f), src, f + ".distance_mm") * kMm;
  return loc;
}

// Numbers rounded to 0.1 um in millimetre files keep them short and exact enough.
double mm(double v) {
  return std::round(v / kMm * 1e4) / 1e4;
}

}  // namespace

VesselTree parse_vessel_tree(std::string_view json_text, const std::string& src) {
  json j;
  try {
    j = json::parse(json_text.begin(), json_text.end());
  } catch (const json::parse_error& e) {
    throw InputError(src, "json", std::string("expected valid JSON: ") + e.what());
  }
  if (!j.is_object()) throw InputError(src, "json", "expected an object at the top level");
  only_keys(j,
            {"format", "version", "name", "coordinates", "open_start", "segments", "lesions",
             "access", "target", "heart"},
            src, "");
  if (text(need(j, "format", src, ""), src, "format") != "vcsim-anatomy")
    throw InputError(src, "format", "expected \"vcsim-anatomy\"");
  if (number(need(j, "version", src, ""), src, "version") != 1.0)
    throw InputError(src, "version", "expected 1");
  if (j.contains("coordinates") && text(j["coordinates"], src, "coordinates") != "LPS")
    throw InputError(src, "coordinates", "expected \"LPS\" (DICOM patient coordinates)");
  VesselTree t;
  t.name = j.contains("name") ? text(j["name"], src, "name") : std::string("unnamed");
  if (j.contains("open_start")) {
    if (!j["open_start"].is_boolean())
      throw InputError(src, "open_start", "expected true or false");
    t.open_start = j["open_start"].get<bool>();
  }
  const json& segs = need(j, "segments", src, "");
  if (!segs.is_array() || segs.empty())
    throw InputError(src, "segments", "expected a non-empty array");
  for (std::size_t i = 0; i < segs.size(); ++i) {
    const std::string f = at("segments", i);
    const json& s = segs[i];
    if (!s.is_object()) throw InputError(src, f, "expected an object");
    only_keys(s, {"name", "kind", "parent", "points_mm", "radii_mm", "radius_mm", "closed_end"},
              src, f);
    VesselSegment seg;
    seg.name = text(need(s, "name", src, f), src, f + ".name");
    if (t.find(seg.name) >= 0)
      throw InputError(src, f + ".name", "expected a unique name, '" + seg.name + "' repeats");
    if (s.contains("kind"))
      seg.kind = kind_from(text(s["kind"], src, f + ".kind"), src, f + ".kind");
    if (s.contains("parent") && !s["parent"].is_null()) {
      const std::string p = text(s["parent"], src, f + ".parent");
      seg.parent = t.find(p);
      if (seg.parent < 0)
        throw InputError(src, f + ".parent",
                         "expected the name of an earlier segment, got '" + p + "'");
    }
    const json& pts = need(s, "points_mm", src, f);
    if (!pts.is_array()) throw InputError(src, f + ".points_mm", "expected an array of [x, y, z]");
    for (std::size_t k = 0; k < pts.size(); ++k)
      seg.points.push_back(vec3(pts[k], src, at(f + ".points_mm", k), kMm));
    if (s.contains("radii_mm") == s.contains("radius_mm"))
      throw InputError(src, f + ".radii_mm",
                       "expected either radii_mm (one per point) or radius_mm");
    if (s.contains("radius_mm")) {
      seg.radii.assign(seg.points.size(), number(s["radius_mm"], src, f + ".radius_mm") * kMm);
    } else {
      const json& r = s["radii_mm"];
      if (!r.is_array()) throw InputError(src, f + ".radii_mm", "expected an array of numbers");
      for (std::size_t k = 0; k < r.size(); ++k)
        seg.radii.push_back(number(r[k], src, at(f + ".radii_mm", k)) * kMm);
    }
    if (s.contains("closed_end")) {
      if (!s["closed_end"].is_boolean())
        throw InputError(src, f + ".closed_end", "expected true or false");
      seg.closed_end = s["closed_end"].get<bool>();
    }
    t.segments.push_back(std::move(seg));
  }
  if (j.contains("lesions")) {
    const json& ls = j["lesions"];
    if (!ls.is_array()) throw InputError(src, "lesions", "expected an array");
    for (std::size_t i = 0; i < ls.size(); ++i) {
      const std::string f = at("lesions", i);
      const json& l = ls[i];
      if (!l.is_object()) throw InputError(src, f, "expected an object");
      only_keys(l,
                {"segment", "distance_mm", "length_mm", "diameter_reduction_percent",
                 "eccentricity", "angle_deg"},
                src, f);
      Lesion les;
      const std::string name = text(need(l, "segment", src, f), src, f + ".segment");
      les.segment = t.find(name);
      if (les.segment < 0) throw InputError(src, f + ".segment", "no segment named '" + name + "'");
      les.distance = number(need(l, "distance_mm", src, f), src, f + ".distance_mm") * kMm;
      les.length = number(need(l, "length_mm", src, f), src, f + ".length_mm") * kMm;
      les.diameter_reduction = number(need(l, "diameter_reduction_percent", src, f), src,
                                      f + ".diameter_reduction_percent") /
                               100.0;
      if (l.contains("eccentricity"))
        les.eccentricity = number(l["eccentricity"], src, f + ".eccentricity");
      if (l.contains("angle_deg")) les.angle = number(l["angle_deg"], src, f + ".angle_deg") * kDeg;
      t.lesions.push_back(les);
    }
  }
  t.access = j.contains("access") ? location(j["access"], t, src, "access") : TreeLocation{0, 0.0};
  if (j.contains("target")) {
    t.target = location(j["target"], t, src, "target");
  } else {
    t.target.segment = t.num_segments() - 1;
    t.target.distance = segment_length(t.segments.back());
  }
  if (j.contains("heart")) {
    const json& h = j["heart"];
    if (!h.is_object()) throw InputError(src, "heart", "expected an object");
    only_keys(h, {"centre_mm", "axis", "anterior", "radii_mm"}, src, "heart");
    HeartModel hm;
    hm.centre = vec3(need(h, "centre_mm", src, "heart"), src, "heart.centre_mm", kMm);
    hm.axis = vec3(need(h, "axis", src, "heart"), src, "heart.axis", 1.0);
    Vec3 ant = vec3(need(h, "anterior", src, "heart"), src, "heart.anterior", 1.0);
    hm.radii = vec3(need(h, "radii_mm", src, "heart"), src, "heart.radii_mm", kMm);
    if (hm.axis.norm() < 1e-9) throw InputError(src, "heart.axis", "expected a non-zero vector");
    hm.axis.normalize();
    ant -= ant.dot(hm.axis) * hm.axis;
    if (ant.norm() < 1e-9)
      throw InputError(src, "heart.anterior", "expected a vector not parallel to the axis");
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
    os << '[' << json(std::round(p.x() / scale * 1e4) / 1e4).dump() << ", "
       << json(std::round(p.y() / scale * 1e4) / 1e4).dump() << ", "
       << json(std::round(p.z() / scale * 1e4) / 1e4).dump() << ']';
  };
  os << "{\n  \"format\": \"vcsim-anatomy\",\n  \"version\": 1,\n  \"name\": "
     << json(t.name).dump()
     << ",\n  \"coordinates\": \"LPS\",\n  \"open_start\": " << (t.open_start ? "true" : "false")
     << ",\n";
  auto loc = [&](const char* key, const TreeLocation& l) {
    os << "  \"" << key << "\": {\"segment\": " << json(t.segments[l.segment].name).dump()
       << ", \"distance_mm\": " << json(mm(l.distance)).dump() << "},\n";
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
    os << (i ? ",\n" : "\n") << "    {\"segment\": " << json(t.segments[l.segment].name).dump()
       << ", \"distance_mm\": " << json(mm(l.distance)).dump()
       << ", \"length_mm\": " << json(mm(l.length)).dump() << ", \"diameter_reduction_percent\": "
       << json(std::round(l.diameter_reduction * 1e6) / 1e4).dump()
       << ", \"eccentricity\": " << json(l.eccentricity).dump()
       << ", \"angle_deg\": " << json(std::round(l.angle / kDeg * 1e4) / 1e4).dump() << "}";
  }
  os << (t.lesions.empty() ? "" : "\n  ") << "],\n  \"segments\": [";
  for (std::size_t i = 0; i < t.segments.size(); ++i) {
    const VesselSegment& s = t.segments[i];
    os << (i ? ",\n" : "\n") << "    {\"name\": " << json(s.name).dump() << ", \"kind\": \""
       << to_string(s.kind) << "\", \"parent\": "
       << (s.parent < 0 ? std::string("null") : json(t.segments[s.parent].name).dump())
       << ", \"closed_end\": " << (s.closed_end ? "true" : "false") << ",\n     \"points_mm\": [";
    for (std::size_t k = 0; k < s.points.size(); ++k) {
      os << (k ? ",\n       " : "\n       ");
      v3(s.points[k], kMm);
    }
    os << "],\n     \"radii_mm\": [";
    for (std::size_t k = 0; k < s.radii.size(); ++k)
      os << (k ? (k % 10 ? ", " : ",\n       ") : "") << json(mm(s.radii[k])).dump();
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
