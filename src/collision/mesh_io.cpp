// Mesh import through assimp (STL, OBJ, PLY) with checks at the boundary, and simple writers.
#include "vcsim/mesh_io.h"

#include <assimp/postprocess.h>
#include <assimp/scene.h>
#include <assimp/Importer.hpp>

#include <algorithm>
#include <bit>
#include <cctype>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <sstream>
#include <string_view>
#include <unordered_map>

namespace vcsim {

namespace {

static_assert(std::endian::native == std::endian::little, "binary STL I/O assumes little endian");

std::string lower_extension(const std::string& path) {
  std::string ext = std::filesystem::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return ext.empty() ? ext : ext.substr(1);
}

std::vector<char> read_bytes(const std::string& path) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec))
    throw InputError(path, "file", "an existing mesh file (not found)");
  if (std::filesystem::is_directory(path, ec))
    throw InputError(path, "file", "a mesh file, not a directory");
  const auto size = std::filesystem::file_size(path, ec);
  if (!ec && size > kMaxMeshFileBytes)
    throw InputError(path, "file",
                     "a mesh file of at most 1 GiB, got " + std::to_string(size) + " bytes");
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError(path, "file", "a readable mesh file");
  std::vector<char> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (in.bad()) throw InputError(path, "file", "a readable mesh file (read error)");
  return bytes;
}

// Keywords as assimp matches them: exactly, in lower case ("verTex" made it count too few
// vertices, fail and leak).
bool same_word(const std::string& token, const char* word) {
  return token == word;
}

// Text that assimp's line readers and vcsim's token checks split alike: no control characters
// but tab, carriage return and line feed (a vertical tab is white space to one and not the other),
// and a carriage return only in a CR LF line end (assimp ends a line at a lone one).
void check_text(std::string_view text, const std::string& path, const char* what) {
  for (std::size_t i = 0; i < text.size(); ++i) {
    const auto c = static_cast<unsigned char>(text[i]);
    if ((c < 0x20 && c != '\t' && c != '\n' && c != '\r') || c == 0x7f ||
        (c == '\r' && (i + 1 == text.size() || text[i + 1] != '\n')))
      throw InputError(path, what,
                       "text without control characters (a carriage return only before a line "
                       "feed), found byte " +
                           std::to_string(c) + " at offset " + std::to_string(i));
  }
}

// A decimal number as assimp's fast_atof reads one: [+-] digits [. digits] [e [+-] digits], or
// with no digits before the point. strtod also takes "inf", "nan" and hexadecimal, which assimp
// does not.
bool is_decimal(std::string_view t) {
  std::size_t i = 0;
  auto digits = [&] {
    const std::size_t from = i;
    while (i < t.size() && std::isdigit(static_cast<unsigned char>(t[i]))) ++i;
    return i - from;
  };
  if (i < t.size() && (t[i] == '+' || t[i] == '-')) ++i;
  std::size_t n = digits();
  if (i < t.size() && t[i] == '.') {
    ++i;
    n += digits();
  }
  if (n == 0) return false;
  if (i < t.size() && (t[i] == 'e' || t[i] == 'E')) {
    ++i;
    if (i < t.size() && (t[i] == '+' || t[i] == '-')) ++i;
    if (digits() == 0) return false;
  }
  return i == t.size();
}

// The ASCII STL grammar, checked before assimp sees the file, line by line as assimp reads it:
// assimp 5.2 leaks memory when it fails inside a facet (a file cut short, a vertex's numbers
// split over two lines), and its messages do not say where the file went wrong.
void check_ascii_stl(std::span<const char> bytes, const std::string& path) {
  const std::string_view all(bytes.data(), bytes.size());
  check_text(all, path, "contents");
  // The lines of a facet after "facet normal": their words and how many numbers follow.
  static constexpr std::pair<const char*, int> kFacet[] = {{"outer loop", 0}, {"vertex", 3},
                                                           {"vertex", 3},     {"vertex", 3},
                                                           {"endloop", 0},    {"endfacet", 0}};
  std::uint64_t facet = 0, line_no = 0;
  int in_facet = -1;  // the index in kFacet of the next line, -1 outside a facet
  bool in_solid = false;
  std::string got;
  auto fail = [&](const std::string& expected) {
    return InputError(path,
                      "line " + std::to_string(line_no) + " (facet " + std::to_string(facet) + ")",
                      "an ASCII STL line " + expected +
                          (got.empty() ? ", got the end of file" : ", got '" + got + "'"));
  };
  for (std::size_t at = 0; at <= all.size();) {
    std::size_t nl = all.find('\n', at);
    if (nl == std::string_view::npos) nl = all.size();
    const std::string_view line = all.substr(at, nl - at);
    at = nl + 1;
    ++line_no;
    std::vector<std::string> w;
    {
      std::istringstream ls{std::string(line)};
      for (std::string x; ls >> x;) w.push_back(x);
    }
    if (w.empty()) continue;
    got = std::string(line.substr(0, 60));
    auto is = [&](std::size_t i, const char* word) {
      return i < w.size() && same_word(w[i], word);
    };
    auto numbers_from = [&](std::size_t i, int n) {
      if (w.size() != i + static_cast<std::size_t>(n)) return false;
      for (std::size_t k = i; k < w.size(); ++k)
        if (!is_decimal(w[k])) {
          got = w[k];
          return false;
        }
      return true;
    };
    if (!in_solid) {
      if (!is(0, "solid")) throw fail("'solid'");
      in_solid = true;
    } else if (in_facet < 0) {
      if (is(0, "endsolid")) {
        in_solid = false;
      } else if (is(0, "facet") && is(1, "normal") && numbers_from(2, 3)) {
        in_facet = 0;
      } else {
        throw fail("'facet normal <x> <y> <z>' (finite decimals) or 'endsolid'");
      }
    } else {
      const auto [word, n] = kFacet[in_facet];
      const bool two = std::string_view(word) == "outer loop";
      const bool ok = two ? w.size() == 2 && is(0, "outer") && is(1, "loop")
                          : is(0, word) && numbers_from(1, n);
      if (!ok) throw fail(std::string("'") + word + (n ? " <x> <y> <z>' (finite decimals)" : "'"));
      if (++in_facet == 6) {
        in_facet = -1;
        if (++facet > kMaxMeshTriangles)
          throw InputError(path, "facets",
                           "at most " + std::to_string(kMaxMeshTriangles) + " triangles");
      }
    }
  }
  got.clear();
  ++line_no;
  if (in_facet >= 0) throw fail("'" + std::string(kFacet[in_facet].first) + "'");
  if (in_solid) throw fail("'endsolid'");
  if (facet == 0) throw InputError(path, "facets", "an ASCII STL with at least one facet");
}

// assimp guesses binary vs ASCII STL on its own and reads whatever a header claims; a
// truncated or padded binary file is refused here first, with a precise message.
void check_stl(std::span<const char> bytes, const std::string& path) {
  const std::size_t size = bytes.size();
  if (size >= 84) {
    std::uint32_t n = 0;
    std::memcpy(&n, bytes.data() + 80, 4);
    if (size == 84 + 50 * static_cast<std::uint64_t>(n)) {
      if (n == 0) throw InputError(path, "triangle count", "a binary STL with at least 1 triangle");
      if (n > kMaxMeshTriangles)
        throw InputError(path, "triangle count",
                         "at most " + std::to_string(kMaxMeshTriangles) + " triangles, got " +
                             std::to_string(n));
      return;
    }
  }
  // ASCII: starts with "solid" and is text (binary files may also start with "solid").
  std::size_t i = 0;
  while (i < size && std::isspace(static_cast<unsigned char>(bytes[i]))) ++i;
  const bool solid = size - i >= 5 && std::memcmp(bytes.data() + i, "solid", 5) == 0;
  const auto head = bytes.first(std::min<std::size_t>(size, 4096));
  const bool text = std::find(head.begin(), head.end(), '\0') == head.end();
  if (solid && text) {
    check_ascii_stl(bytes, path);
    return;
  }
  if (size < 84)
    throw InputError(path, "size",
                     "an ASCII STL starting with 'solid' or a binary STL of at least 84 bytes "
                     "(80-byte header and a triangle count), got " +
                         std::to_string(size) + " bytes");
  std::uint32_t n = 0;
  std::memcpy(&n, bytes.data() + 80, 4);
  throw InputError(path, "size",
                   "84 + 50 n = " + std::to_string(84 + 50 * static_cast<std::uint64_t>(n)) +
                       " bytes for the n = " + std::to_string(n) +
                       " triangles its binary header claims, got " + std::to_string(size) +
                       " bytes (truncated or not an STL file)");
}

// assimp fills missing PLY elements silently (it reads face lines as vertices when vertices run
// short), aborts on a binary face element with a scalar after its list, and loops over whatever
// count a header declares; so the header is checked against what vcsim reads (a "vertex" element
// of scalars with x, y and z, then a "face" element whose only property is an integer list) and
// the body is walked once against it: every declared entry must be there, and nothing else.
void check_ply(std::span<const char> bytes, const std::string& path) {
  const std::string_view all(bytes.data(), bytes.size());
  // The header is whole lines, "ply" first and "end_header" last (assimp loops for ever on a
  // header whose last line is "end_headero"), each line a keyword assimp reads.
  std::size_t end = std::string_view::npos, body_start = 0;
  for (std::size_t at = 0, n = 0; at < all.size(); ++n) {
    auto nl = all.find('\n', at);
    if (nl == std::string_view::npos) nl = all.size();
    std::string_view line = all.substr(at, nl - at);
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    const std::string_view word = line.substr(0, line.find(' '));
    if (n == 0 ? line != "ply"
               : word != "format" && word != "comment" && word != "obj_info" && word != "element" &&
                     word != "property" && line != "end_header")
      throw InputError(path, "header line " + std::to_string(n + 1),
                       "a PLY header: 'ply', then format, comment, obj_info, element and property "
                       "lines, then 'end_header'");
    at = nl + 1;
    if (line == "end_header") {
      end = nl;
      body_start = std::min(at, all.size());
      break;
    }
  }
  if (end == std::string_view::npos)
    throw InputError(path, "header", "a PLY header: 'ply' ... 'end_header'");
  check_text(all.substr(0, end), path, "header");

  struct Property {
    int size;        // bytes of a scalar, or of each list item
    int count_size;  // bytes of a list's count, 0 for a scalar
    bool integer;    // an integer scalar (in ASCII written without a point or an exponent)
  };
  struct Element {
    std::string name;
    std::uint64_t count;
    std::vector<Property> props;
    std::vector<std::string> names;
  };
  auto type_size = [&](const std::string& t, bool integer) {
    if (t == "char" || t == "uchar" || t == "int8" || t == "uint8") return 1;
    if (t == "short" || t == "ushort" || t == "int16" || t == "uint16") return 2;
    if (t == "int" || t == "uint" || t == "int32" || t == "uint32") return 4;
    if (!integer && (t == "float" || t == "float32")) return 4;
    if (!integer && (t == "double" || t == "float64")) return 8;
    throw InputError(
        path, "header",
        std::string(integer ? "an integer" : "a known") + " PLY property type, got '" + t + "'");
  };
  std::vector<Element> elements;
  std::string format;
  std::istringstream header(std::string(all.substr(0, end)));
  for (std::string line; std::getline(header, line);) {
    std::istringstream ls(line);
    std::string word;
    ls >> word;
    if (word == "format") {
      ls >> format;
    } else if (word == "element") {
      Element e;
      std::string count;
      if (!(ls >> e.name >> count) || count.find_first_not_of("0123456789") != std::string::npos ||
          count.size() > 12)
        throw InputError(path, "header",
                         "'element <name> <count>' with a count below 10^12, got '" + line + "'");
      e.count = std::stoull(count);
      const std::size_t want = elements.size();
      if (want > 1 || e.name != (want == 0 ? "vertex" : "face"))
        throw InputError(
            path, "header",
            "a 'vertex' element then a 'face' element and no other, got 'element " + e.name + "'");
      elements.push_back(e);
    } else if (word == "property") {
      if (elements.empty()) throw InputError(path, "header", "'element' before 'property'");
      Element& e = elements.back();
      std::string type, name;
      ls >> type;
      if (type == "list") {
        std::string count_type, item_type;
        ls >> count_type >> item_type >> name;
        if (e.name != "face" || !e.props.empty())
          throw InputError(path, "element " + e.name,
                           "a list property only as the face element's one property (vertex "
                           "indices); per-face colours or other face properties are not read");
        e.props.push_back({type_size(item_type, true), type_size(count_type, true), true});
      } else {
        ls >> name;
        if (e.name != "vertex")
          throw InputError(path, "element " + e.name,
                           "only the list of vertex indices in a face, got property '" + name +
                               "' (per-face colours or other face properties are not read)");
        const bool integer =
            type != "float" && type != "float32" && type != "double" && type != "float64";
        e.props.push_back({type_size(type, false), 0, integer});
      }
      e.names.push_back(name);
    }
  }
  if (elements.size() != 2 || elements[1].props.empty())
    throw InputError(path, "header", "a 'vertex' element and a 'face' element with a vertex list");
  for (const char* axis : {"x", "y", "z"})
    if (std::find(elements[0].names.begin(), elements[0].names.end(), axis) ==
        elements[0].names.end())
      throw InputError(path, "element vertex", std::string("a property '") + axis + "'");
  if (elements[0].count > kMaxMeshVertices)
    throw InputError(path, "element vertex",
                     "at most " + std::to_string(kMaxMeshVertices) + " vertices, got " +
                         std::to_string(elements[0].count));
  if (elements[1].count > kMaxMeshTriangles)
    throw InputError(path, "element face",
                     "at most " + std::to_string(kMaxMeshTriangles) + " faces, got " +
                         std::to_string(elements[1].count));
  // Each entry takes at least a byte per property (binary) or two characters (ASCII): a count the
  // file cannot hold is refused before anything loops over it.
  const std::uint64_t body = bytes.size() - std::min(bytes.size(), body_start);
  for (const Element& e : elements)
    if (e.count > body / (e.props.size() * (format == "ascii" ? 2 : 1)))
      throw InputError(path, "element " + e.name,
                       std::to_string(e.count) + " entries as the header declares; the file's " +
                           std::to_string(body) + " bytes after the header cannot hold them");
  auto short_file = [&](const Element& e, std::uint64_t i) {
    return InputError(path, "element " + e.name,
                      std::to_string(e.count) + " entries as the header declares; the file " +
                          "ends at entry " + std::to_string(i));
  };
  std::uint64_t triangles = 0;  // the faces' polygons as triangles
  auto add_polygon = [&](std::uint64_t n, std::uint64_t i) {
    if (n < 3) throw InputError(path, "face " + std::to_string(i), "at least 3 vertex indices");
    triangles += n - 2;
    if (triangles > kMaxMeshTriangles)
      throw InputError(path, "element face",
                       "at most " + std::to_string(kMaxMeshTriangles) + " triangles");
  };
  const std::uint64_t nv = elements[0].count;
  auto bad_index = [&](std::uint64_t i) {
    return InputError(path, "face " + std::to_string(i),
                      "vertex indices below the " + std::to_string(nv) + " vertices");
  };
  if (format == "ascii") {
    // assimp reads an ASCII PLY line by line: each entry is one line with exactly its values.
    check_text(all.substr(body_start), path, "contents");
    std::size_t at = body_start;
    auto next_line = [&]() {
      std::size_t nl = all.find('\n', at);
      if (nl == std::string_view::npos) nl = all.size();
      const std::string_view line = all.substr(at, nl - at);
      at = std::min(nl + 1, all.size() + 1);
      return line;
    };
    for (const Element& e : elements) {
      for (std::uint64_t i = 0; i < e.count; ++i) {
        if (at > all.size()) throw short_file(e, i);
        std::istringstream text{std::string(next_line())};
        std::string token;
        for (const Property& p : e.props) {
          token.clear();
          text >> token;
          const bool whole = token.find_first_not_of("+-0123456789") == std::string::npos;
          if (token.empty() || !is_decimal(token) || (p.integer && !whole))
            throw InputError(path, "element " + e.name + " " + std::to_string(i),
                             "a line of " + std::to_string(e.props.size()) +
                                 " numbers (whole ones for integer properties)" +
                                 (token.empty() ? std::string() : ", got '" + token + "'"));
          if (p.count_size == 0) continue;
          if (token.find_first_not_of("0123456789") != std::string::npos || token.size() > 9)
            throw InputError(path, "element " + e.name + " " + std::to_string(i),
                             "a whole number of vertex indices, got '" + token + "'");
          const std::uint64_t n = std::stoull(token);
          add_polygon(n, i);
          for (std::uint64_t k = 0; k < n; ++k) {
            if (!(text >> token) || token.find_first_not_of("0123456789") != std::string::npos ||
                token.size() > 9 || std::stoull(token) >= nv)
              throw bad_index(i);
          }
        }
        if (text >> token)
          throw InputError(path, "element " + e.name + " " + std::to_string(i),
                           "a line with only the header's properties, found '" + token + "'");
      }
    }
    for (std::string_view rest = all.substr(std::min(at, all.size())); !rest.empty();
         rest.remove_prefix(1))
      if (!std::isspace(static_cast<unsigned char>(rest.front())))
        throw InputError(path, "contents", "no data after the elements the header declares");
  } else if (format == "binary_little_endian" || format == "binary_big_endian") {
    const bool swap = format == "binary_big_endian";
    std::size_t at = body_start;
    for (const Element& e : elements) {
      for (std::uint64_t i = 0; i < e.count; ++i) {
        for (const Property& p : e.props) {
          if (p.count_size == 0) {
            at += static_cast<std::size_t>(p.size);
            if (at > bytes.size()) throw short_file(e, i);
            continue;
          }
          if (at + static_cast<std::size_t>(p.count_size) > bytes.size()) throw short_file(e, i);
          unsigned char c[8] = {};
          std::memcpy(c, bytes.data() + at, static_cast<std::size_t>(p.count_size));
          if (swap) std::reverse(c, c + p.count_size);
          std::uint64_t n = 0;
          std::memcpy(&n, c, static_cast<std::size_t>(p.count_size));  // little-endian host
          at += static_cast<std::size_t>(p.count_size);
          if (n > (bytes.size() - at) / static_cast<std::size_t>(p.size)) throw short_file(e, i);
          add_polygon(n, i);
          for (std::uint64_t k = 0; k < n; ++k, at += static_cast<std::size_t>(p.size)) {
            unsigned char v[8] = {};
            std::memcpy(v, bytes.data() + at, static_cast<std::size_t>(p.size));
            if (swap) std::reverse(v, v + p.size);
            std::uint64_t index = 0;
            std::memcpy(&index, v, static_cast<std::size_t>(p.size));
            if (index >= nv) throw bad_index(i);  // a negative index reads as a large one
          }
        }
      }
    }
    if (at != bytes.size())
      throw InputError(path, "contents",
                       "no data after the elements the header declares, found " +
                           std::to_string(bytes.size() - at) + " more bytes");
  } else {
    throw InputError(path, "format", "ascii, binary_little_endian or binary_big_endian");
  }
}

// OBJ lines checked before assimp reads them, as it reads them: vertices ("v x y z [w]" or with a
// colour, "vn", "vt") of decimal numbers, so that both count the same; faces, lines and points
// of indices "v[/vt][/vn]" that name an element of the file (assimp throws on one out of range,
// leaking memory); the vertices and the faces' triangles within the limits.
void check_obj(std::span<const char> bytes, const std::string& path) {
  const std::string_view all(bytes.data(), bytes.size());
  check_text(all, path, "contents");
  std::uint64_t count[3] = {0, 0, 0};  // v, vt, vn so far
  std::uint64_t triangles = 0, line_no = 0;
  struct Ref {
    std::uint64_t line;
    int kind;  // 0 v, 1 vt, 2 vn
    long long index;
  };
  std::vector<Ref> refs;  // positive indices, checked against the file's counts at its end
  for (std::size_t at = 0; at < all.size();) {
    std::size_t nl = all.find('\n', at);
    if (nl == std::string_view::npos) nl = all.size();
    const std::string_view text = all.substr(at, nl - at);
    std::istringstream ls{std::string(text)};
    at = nl + 1;
    ++line_no;
    std::string key;
    if (!(ls >> key)) continue;
    // assimp dispatches on a line's first character: any line starting with f, l or p is read as
    // indices (an "f" followed by other bytes made it read past its buffer), one starting with v
    // as a vertex kind.
    if ((std::strchr("flpv", key[0]) != nullptr && text[0] != key[0]) ||
        (std::strchr("flp", key[0]) != nullptr && key.size() > 1) ||
        (key[0] == 'v' && key != "v" && key != "vt" && key != "vn"))
      throw InputError(path, "line " + std::to_string(line_no),
                       "an OBJ keyword (v, vt, vn, f, l, p, ...) at the start of the line, got '" +
                           key.substr(0, 20) + "'");
    std::vector<std::string> w;
    for (std::string x; ls >> x;) w.push_back(x);
    auto fail = [&](const std::string& expected) {
      return InputError(path, "line " + std::to_string(line_no), expected);
    };
    const int kind = key == "v" ? 0 : key == "vt" ? 1 : key == "vn" ? 2 : -1;
    if (kind >= 0) {
      const bool ok = kind == 0   ? w.size() == 3 || w.size() == 4 || w.size() == 6
                      : kind == 1 ? w.size() >= 1 && w.size() <= 3
                                  : w.size() == 3;
      // A number beginning with '.' is none to assimp's count of a line's components (a
      // coloured vertex "v x y z r .5 b" counted as one of five leaked the mesh it was building):
      // refused, so that both count the same.
      if (!ok || !std::all_of(w.begin(), w.end(),
                              [](const std::string& x) { return is_decimal(x) && x[0] != '.'; }))
        throw fail("'" + key +
                   "' and its finite decimal numbers, each beginning with a digit or a sign (v: 3, "
                   "4 or 6; vt: 1-3; vn: 3)");
      if (++count[kind] > kMaxMeshVertices)
        throw fail("at most " + std::to_string(kMaxMeshVertices) + " vertices");
      continue;
    }
    if (key != "f" && key != "l" && key != "p") continue;
    if (w.empty()) throw fail("'" + key + "' with vertex indices");
    // A line of one point, alone in a group, leaked the mesh assimp was building (the OBJ
    // campaign, 2026-11-26); a polyline has two points at least, a face three.
    if (key == "l" && w.size() < 2) throw fail("'l' with two vertex indices at least");
    if (key == "f" && w.size() < 3) throw fail("'f' with three vertex indices at least");
    for (const std::string& corner : w) {
      // v, v/vt, v//vn or v/vt/vn: integers, non-zero, negative ones relative to what is before.
      std::size_t from = 0;
      for (int part = 0; part < 3 && from <= corner.size(); ++part) {
        const std::size_t slash = std::min(corner.find('/', from), corner.size());
        const std::string num = corner.substr(from, slash - from);
        from = slash + 1;
        if (num.empty() && part == 1 && slash < corner.size()) continue;  // v//vn
        const bool digits =
            !num.empty() && num.size() <= 12 &&
            num.find_first_not_of("0123456789", num[0] == '-') == std::string::npos && num != "-";
        const long long v = digits ? std::stoll(num) : 0;
        if (v == 0)
          throw fail("indices v[/vt][/vn] (1-based, or negative: relative), got '" + corner + "'");
        if (v < 0 && static_cast<std::uint64_t>(-v) > count[part])
          throw fail("a relative index within the " + std::to_string(count[part]) +
                     " elements before it, got '" + corner + "'");
        if (v > 0) refs.push_back({line_no, part, v});
        if (slash == corner.size()) break;
        if (part == 2) throw fail("at most three indices a corner, got '" + corner + "'");
      }
    }
    if (key == "f" && w.size() >= 3) triangles += w.size() - 2;
    if (triangles > kMaxMeshTriangles)
      throw fail("at most " + std::to_string(kMaxMeshTriangles) + " triangles");
  }
  for (const Ref& r : refs)
    if (static_cast<std::uint64_t>(r.index) > count[r.kind])
      throw InputError(path, "line " + std::to_string(r.line),
                       std::string("indices up to the file's ") + std::to_string(count[r.kind]) +
                           (r.kind == 0   ? " vertices"
                            : r.kind == 1 ? " texture coordinates"
                                          : " normals") +
                           ", got " + std::to_string(r.index));
}

// Exact-coordinate key for joining duplicate vertices (STL stores every triangle's corners).
struct Key {
  float x, y, z;
  bool operator==(const Key& o) const { return x == o.x && y == o.y && z == o.z; }
};
struct KeyHash {
  std::size_t operator()(const Key& k) const {
    auto bits = [](float f) { return static_cast<std::size_t>(std::bit_cast<std::uint32_t>(f)); };
    return bits(k.x) * 73856093u ^ bits(k.y) * 19349663u ^ bits(k.z) * 83492791u;
  }
};

std::string fmt(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.9g", v);
  return buf;
}

void check_written(std::ofstream& out, const std::string& path) {
  out.close();
  if (!out) throw InputError(path, "file", "a writable path (writing failed)");
}

}  // namespace

TriangleMesh load_mesh(const std::string& path, const MeshLoadOptions& options,
                       MeshReport* report) {
  require_positive(options.unit_scale, path, "unit_scale");
  const std::string ext = lower_extension(path);
  if (ext != "stl" && ext != "obj" && ext != "ply")
    throw InputError(path, "extension", "one of .stl, .obj, .ply, got '." + ext + "'");
  const std::vector<char> bytes = read_bytes(path);
  return load_mesh_bytes(bytes, ext, path, options, report);
}

TriangleMesh load_mesh_bytes(std::span<const char> bytes, const std::string& ext,
                             const std::string& path, const MeshLoadOptions& options,
                             MeshReport* report) {
  require_positive(options.unit_scale, path, "unit_scale");
  if (ext != "stl" && ext != "obj" && ext != "ply")
    throw InputError(path, "extension", "one of .stl, .obj, .ply, got '." + ext + "'");
  if (bytes.empty()) throw InputError(path, "file", "a non-empty ." + ext + " file, got 0 bytes");
  if (bytes.size() > kMaxMeshFileBytes)
    throw InputError(path, "file", "a mesh file of at most 1 GiB");
  if (ext == "stl") check_stl(bytes, path);
  if (ext == "ply") check_ply(bytes, path);
  if (ext == "obj") check_obj(bytes, path);

  // Points and lines are dropped, polygons triangulated, node transforms baked in; the
  // validation step rejects out-of-range indices and other structural damage.
  Assimp::Importer importer;
  importer.SetPropertyInteger(AI_CONFIG_PP_SBP_REMOVE,
                              aiPrimitiveType_POINT | aiPrimitiveType_LINE);
  const unsigned flags = aiProcess_Triangulate | aiProcess_SortByPType |
                         aiProcess_PreTransformVertices | aiProcess_ValidateDataStructure;
  const aiScene* scene =
      importer.ReadFileFromMemory(bytes.data(), bytes.size(), flags, ext.c_str());
  if (scene == nullptr)
    throw InputError(path, "contents",
                     "a valid ." + ext + " file (" + importer.GetErrorString() + ")");
  if ((scene->mFlags & AI_SCENE_FLAGS_INCOMPLETE) != 0 || scene->mNumMeshes == 0)
    throw InputError(path, "contents", "a ." + ext + " file with a triangle mesh");

  TriangleMesh mesh;
  std::unordered_map<Key, int, KeyHash> index;
  for (unsigned mi = 0; mi < scene->mNumMeshes; ++mi) {
    const aiMesh* am = scene->mMeshes[mi];
    if (am == nullptr || am->mVertices == nullptr) continue;
    std::vector<int> local(am->mNumVertices);
    for (unsigned v = 0; v < am->mNumVertices; ++v) {
      const aiVector3D& p = am->mVertices[v];
      if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z))
        throw InputError(
            path, "vertex " + std::to_string(v),
            "finite coordinates, got (" + fmt(p.x) + ", " + fmt(p.y) + ", " + fmt(p.z) + ")");
      // -0 and +0 are the same point.
      const Key k{p.x + 0.0f, p.y + 0.0f, p.z + 0.0f};
      const auto [it, inserted] = index.try_emplace(k, mesh.num_vertices());
      if (inserted) mesh.vertices.push_back(Vec3(p.x, p.y, p.z) * options.unit_scale);
      local[v] = it->second;
    }
    for (unsigned f = 0; f < am->mNumFaces; ++f) {
      const aiFace& face = am->mFaces[f];
      if (face.mNumIndices != 3) continue;
      std::array<int, 3> tri{};
      for (int k = 0; k < 3; ++k) {
        const unsigned v = face.mIndices[k];
        if (v >= am->mNumVertices)
          throw InputError(path, "face " + std::to_string(f),
                           "vertex indices below " + std::to_string(am->mNumVertices));
        tri[k] = local[v];
      }
      mesh.triangles.push_back(tri);
    }
  }
  if (mesh.triangles.empty())
    throw InputError(path, "triangles", "at least one triangle in the ." + ext + " file");

  if (!options.check) return mesh;
  MeshReport r = check_and_repair(mesh, path);
  if (report != nullptr) *report = std::move(r);
  return mesh;
}

void write_stl(const TriangleMesh& mesh, const std::string& path, bool binary, double unit_scale) {
  require_positive(unit_scale, path, "unit_scale");
  const double s = 1.0 / unit_scale;
  std::ofstream out(path, std::ios::binary);
  if (!out) throw InputError(path, "file", "a writable path");
  auto normal = [&](int t) {
    const auto& tri = mesh.triangles[t];
    const Vec3 n = (mesh.vertices[tri[1]] - mesh.vertices[tri[0]])
                       .cross(mesh.vertices[tri[2]] - mesh.vertices[tri[0]]);
    return n.norm() > 0.0 ? Vec3(n.normalized()) : Vec3::Zero();
  };
  if (binary) {
    // The header does not start with "solid", so no reader mistakes the file for ASCII.
    char header[80] = {};
    std::snprintf(header, sizeof header, "vcsim binary STL, winding faces the lumen");
    out.write(header, 80);
    const auto n = static_cast<std::uint32_t>(mesh.triangles.size());
    out.write(reinterpret_cast<const char*>(&n), 4);
    for (int t = 0; t < mesh.num_triangles(); ++t) {
      float rec[12];
      const Vec3 nt = normal(t);
      for (int k = 0; k < 3; ++k) rec[k] = static_cast<float>(nt[k]);
      for (int c = 0; c < 3; ++c)
        for (int k = 0; k < 3; ++k)
          rec[3 + 3 * c + k] = static_cast<float>(mesh.vertices[mesh.triangles[t][c]][k] * s);
      out.write(reinterpret_cast<const char*>(rec), sizeof rec);
      const std::uint16_t attr = 0;
      out.write(reinterpret_cast<const char*>(&attr), 2);
    }
  } else {
    out << "solid vcsim\n";
    for (int t = 0; t < mesh.num_triangles(); ++t) {
      const Vec3 nt = normal(t);
      out << "  facet normal " << fmt(nt.x()) << " " << fmt(nt.y()) << " " << fmt(nt.z())
          << "\n    outer loop\n";
      for (int v : mesh.triangles[t]) {
        const Vec3 p = mesh.vertices[v] * s;
        out << "      vertex " << fmt(p.x()) << " " << fmt(p.y()) << " " << fmt(p.z()) << "\n";
      }
      out << "    endloop\n  endfacet\n";
    }
    out << "endsolid vcsim\n";
  }
  check_written(out, path);
}

void write_obj(const TriangleMesh& mesh, const std::string& path, double unit_scale) {
  require_positive(unit_scale, path, "unit_scale");
  const double s = 1.0 / unit_scale;
  std::ofstream out(path);
  if (!out) throw InputError(path, "file", "a writable path");
  out << "# vcsim lumen mesh; winding faces the lumen\n";
  for (const Vec3& v : mesh.vertices) {
    const Vec3 p = v * s;
    out << "v " << fmt(p.x()) << " " << fmt(p.y()) << " " << fmt(p.z()) << "\n";
  }
  for (const auto& t : mesh.triangles)
    out << "f " << t[0] + 1 << " " << t[1] + 1 << " " << t[2] + 1 << "\n";
  check_written(out, path);
}

void write_ply(const TriangleMesh& mesh, const std::string& path, double unit_scale) {
  require_positive(unit_scale, path, "unit_scale");
  const double s = 1.0 / unit_scale;
  std::ofstream out(path);
  if (!out) throw InputError(path, "file", "a writable path");
  out << "ply\nformat ascii 1.0\ncomment vcsim lumen mesh; winding faces the lumen\n"
      << "element vertex " << mesh.vertices.size()
      << "\nproperty double x\nproperty double y\nproperty double z\n"
      << "element face " << mesh.triangles.size()
      << "\nproperty list uchar int vertex_indices\nend_header\n";
  for (const Vec3& v : mesh.vertices) {
    const Vec3 p = v * s;
    out << fmt(p.x()) << " " << fmt(p.y()) << " " << fmt(p.z()) << "\n";
  }
  for (const auto& t : mesh.triangles) out << "3 " << t[0] << " " << t[1] << " " << t[2] << "\n";
  check_written(out, path);
}

}  // namespace vcsim
