// SimVascular .pth path files (Vascular Model Repository): centrelines as segments without
// parents. Only what the paths need from the XML is read: <path> elements and the x, y, z of each
// <path_point>'s <pos>.
#include <cctype>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "vcsim/anatomy.h"

namespace vcsim {

namespace {

// Value of attribute `name` in the XML tag text `tag` (e.g. x="1.5"); false if absent.
bool attribute(const std::string& tag, const std::string& name, std::string& value) {
  std::size_t p = 0;
  while ((p = tag.find(name, p)) != std::string::npos) {
    const bool start_ok = p == 0 || std::isspace(static_cast<unsigned char>(tag[p - 1]));
    std::size_t q = p + name.size();
    while (q < tag.size() && std::isspace(static_cast<unsigned char>(tag[q]))) ++q;
    if (start_ok && q < tag.size() && tag[q] == '=') {
      ++q;
      while (q < tag.size() && std::isspace(static_cast<unsigned char>(tag[q]))) ++q;
      if (q < tag.size() && (tag[q] == '"' || tag[q] == '\'')) {
        const std::size_t e = tag.find(tag[q], q + 1);
        if (e == std::string::npos) return false;
        value = tag.substr(q + 1, e - q - 1);
        return true;
      }
    }
    p += name.size();
  }
  return false;
}

double parse_number(const std::string& s, const std::string& src, const std::string& field) {
  std::size_t used = 0;
  double v = 0.0;
  try {
    v = std::stod(s, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used == 0 || used != s.size())
    throw InputError(src, field, "expected a number, got '" + s + "'");
  return require_finite(v, src, field);
}

}  // namespace

VesselTree load_pth_paths(const std::string& path, double unit_scale) {
  std::ifstream f(path, std::ios::binary);
  if (!f) throw InputError(path, "file", "expected a readable SimVascular .pth file");
  std::stringstream ss;
  ss << f.rdbuf();
  return parse_pth_paths(ss.str(), path, unit_scale);
}

VesselTree parse_pth_paths(const std::string& text, const std::string& path, double unit_scale) {
  require_positive(unit_scale, path, "unit_scale");
  VesselTree t;
  t.name = std::filesystem::path(path).stem().string();
  // Each <path ...> element holds <path_point> elements with a <pos x= y= z= /> each.
  std::size_t at = 0;
  int index = 0;
  while ((at = text.find("<path ", at)) != std::string::npos) {
    const std::size_t tag_end = text.find('>', at);
    const std::size_t end = text.find("</path>", at);
    if (tag_end == std::string::npos || end == std::string::npos)
      throw InputError(path, "path", "expected a closed <path> element");
    VesselSegment seg;
    std::string id;
    seg.name = t.name;
    // Appended piece by piece: GCC 12 warns falsely on "literal" + std::string (-Wrestrict).
    if (index > 0) {
      seg.name += '_';
      seg.name += attribute(text.substr(at, tag_end - at), "id", id) ? id : std::to_string(index);
    }
    std::size_t p = at;
    int k = 0;
    while ((p = text.find("<path_point", p)) != std::string::npos && p < end) {
      const std::size_t pos = text.find("<pos", p);
      const std::size_t pos_end = pos == std::string::npos ? pos : text.find('>', pos);
      if (pos == std::string::npos || pos_end == std::string::npos || pos > end)
        throw InputError(path, "path_point[" + std::to_string(k) + "]", "expected a <pos x y z/>");
      const std::string tag = text.substr(pos, pos_end - pos);
      Vec3 v;
      for (int a = 0; a < 3; ++a) {
        const std::string axis(1, "xyz"[a]);
        std::string val;
        const std::string field = "path_point[" + std::to_string(k) + "].pos." + axis;
        if (!attribute(tag, axis, val)) throw InputError(path, field, "missing");
        v[a] = require_finite(parse_number(val, path, field) * unit_scale, path, field);
      }
      if (seg.points.empty() || (v - seg.points.back()).norm() > 1e-9) seg.points.push_back(v);
      p = pos_end;
      ++k;
    }
    if (seg.points.size() < 2)
      throw InputError(path, "path[" + std::to_string(index) + "]",
                       "expected at least 2 path points");
    t.segments.push_back(std::move(seg));
    at = end;
    ++index;
  }
  if (t.segments.empty()) throw InputError(path, "path", "no <path> element found");
  t.access = {0, 0.0};
  t.target = {t.num_segments() - 1, 0.0};
  return t;
}

}  // namespace vcsim
