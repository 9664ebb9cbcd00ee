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
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError(path, "file", "a readable mesh file");
  std::vector<char> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (in.bad()) throw InputError(path, "file", "a readable mesh file (read error)");
  return bytes;
}

bool is_number(const std::string& token) {
  char* end = nullptr;
  std::strtod(token.c_str(), &end);
  return end != token.c_str() && *end == '\0';
}

bool same_word(const std::string& token, const char* word) {
  return token.size() == std::strlen(word) &&
         std::equal(token.begin(), token.end(), word, [](char a, char b) {
           return std::tolower(static_cast<unsigned char>(a)) == b;
         });
}

// The ASCII STL grammar, checked before assimp sees the file: assimp 5.2 leaks memory when an
// ASCII STL ends inside a facet, and its messages do not say where the file went wrong.
void check_ascii_stl(const std::vector<char>& bytes, const std::string& path) {
  std::istringstream in(std::string(bytes.begin(), bytes.end()));
  std::string tok;
  int facet = 0;
  auto fail = [&](const std::string& expected) {
    return InputError(path, "facet " + std::to_string(facet),
                      "an ASCII STL facet: " + expected +
                          (tok.empty() ? ", got the end of file" : ", got '" + tok + "'"));
  };
  auto expect_word = [&](const char* word) {
    tok.clear();
    if (!(in >> tok) || !same_word(tok, word)) throw fail(std::string("'") + word + "'");
  };
  auto expect_numbers = [&](int n) {
    for (int i = 0; i < n; ++i) {
      tok.clear();
      if (!(in >> tok) || !is_number(tok)) throw fail("a number");
    }
  };
  bool in_solid = false;
  while (in >> tok) {
    if (!in_solid) {
      if (!same_word(tok, "solid")) throw fail("'solid'");
      in_solid = true;
      // The name runs to the end of the line.
      std::string name;
      std::getline(in, name);
    } else if (same_word(tok, "facet")) {
      expect_word("normal");
      expect_numbers(3);
      expect_word("outer");
      expect_word("loop");
      for (int v = 0; v < 3; ++v) {
        expect_word("vertex");
        expect_numbers(3);
      }
      expect_word("endloop");
      expect_word("endfacet");
      ++facet;
    } else if (same_word(tok, "endsolid")) {
      in_solid = false;
      std::string name;
      std::getline(in, name);
    } else {
      throw fail("'facet' or 'endsolid'");
    }
  }
  tok.clear();
  if (in_solid) throw fail("'endsolid'");
  if (facet == 0) throw InputError(path, "facets", "an ASCII STL with at least one facet");
}

// assimp guesses binary vs ASCII STL on its own and reads whatever a header claims; a
// truncated or padded binary file is refused here first, with a precise message.
void check_stl(const std::vector<char>& bytes, const std::string& path) {
  const std::size_t size = bytes.size();
  if (size >= 84) {
    std::uint32_t n = 0;
    std::memcpy(&n, bytes.data() + 80, 4);
    if (size == 84 + 50 * static_cast<std::uint64_t>(n)) {
      if (n == 0) throw InputError(path, "triangle count", "a binary STL with at least 1 triangle");
      return;
    }
  }
  // ASCII: starts with "solid" and is text (binary files may also start with "solid").
  std::size_t i = 0;
  while (i < size && std::isspace(static_cast<unsigned char>(bytes[i]))) ++i;
  const bool solid = size - i >= 5 && std::memcmp(bytes.data() + i, "solid", 5) == 0;
  const bool text = std::find(bytes.begin(), bytes.begin() + std::min<std::size_t>(size, 4096),
                              '\0') == bytes.begin() + std::min<std::size_t>(size, 4096);
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
// short), so the body is walked once against the header: every declared element must be there,
// and nothing else.
void check_ply(const std::vector<char>& bytes, const std::string& path) {
  const std::string_view all(bytes.data(), bytes.size());
  const auto end = all.find("end_header");
  if (all.rfind("ply", 0) != 0 || end == std::string_view::npos)
    throw InputError(path, "header", "a PLY header: 'ply' ... 'end_header'");
  auto body_start = all.find('\n', end);
  if (body_start == std::string_view::npos)
    body_start = all.size();
  else
    ++body_start;

  struct Property {
    int size;        // bytes of a scalar, or of each list item
    int count_size;  // bytes of a list's count, 0 for a scalar
  };
  struct Element {
    std::string name;
    std::uint64_t count;
    std::vector<Property> props;
  };
  auto type_size = [&](const std::string& t) {
    if (t == "char" || t == "uchar" || t == "int8" || t == "uint8") return 1;
    if (t == "short" || t == "ushort" || t == "int16" || t == "uint16") return 2;
    if (t == "int" || t == "uint" || t == "float" || t == "int32" || t == "uint32" ||
        t == "float32")
      return 4;
    if (t == "double" || t == "float64") return 8;
    throw InputError(path, "header", "a known PLY property type, got '" + t + "'");
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
      if (!(ls >> e.name >> e.count))
        throw InputError(path, "header", "'element <name> <count>', got '" + line + "'");
      elements.push_back(e);
    } else if (word == "property") {
      if (elements.empty()) throw InputError(path, "header", "'element' before 'property'");
      std::string type;
      ls >> type;
      if (type == "list") {
        std::string count_type, item_type;
        ls >> count_type >> item_type;
        elements.back().props.push_back({type_size(item_type), type_size(count_type)});
      } else {
        elements.back().props.push_back({type_size(type), 0});
      }
    }
  }
  auto short_file = [&](const Element& e, std::uint64_t i) {
    return InputError(path, "element " + e.name,
                      std::to_string(e.count) + " entries as the header declares; the file " +
                          "ends at entry " + std::to_string(i));
  };
  if (format == "ascii") {
    std::istringstream body(std::string(all.substr(body_start)));
    std::string token;
    for (const Element& e : elements) {
      for (std::uint64_t i = 0; i < e.count; ++i) {
        for (const Property& p : e.props) {
          if (!(body >> token)) throw short_file(e, i);
          if (!is_number(token))
            throw InputError(path, "element " + e.name + " " + std::to_string(i),
                             "numbers, got '" + token + "'");
          if (p.count_size == 0) continue;
          const long n = std::strtol(token.c_str(), nullptr, 10);
          if (n < 0) throw InputError(path, "element " + e.name, "list sizes >= 0");
          for (long k = 0; k < n; ++k)
            if (!(body >> token) || !is_number(token)) throw short_file(e, i);
        }
      }
    }
    if (body >> token)
      throw InputError(path, "contents",
                       "no data after the elements the header declares, found '" + token + "'");
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
          at += n * static_cast<std::size_t>(p.size);
        }
      }
    }
  } else {
    throw InputError(path, "format", "ascii, binary_little_endian or binary_big_endian");
  }
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
  if (bytes.empty()) throw InputError(path, "file", "a non-empty ." + ext + " file, got 0 bytes");
  if (ext == "stl") check_stl(bytes, path);
  if (ext == "ply") check_ply(bytes, path);

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

}  // namespace vcsim
