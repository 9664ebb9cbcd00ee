// `vcsim anatomy build | info | export | repair` and `vcsim bench anatomy`: the patient's vessel
// tree and lumen mesh, and the per-step cost of cardiac motion.
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "commands.h"
#include "vcsim/anatomy.h"
#include "vcsim/mesh_io.h"
#include "vcsim/units.h"

namespace vcsim::app {

namespace {

struct Source {
  std::string file;         // anatomy JSON, or a lumen mesh (STL/OBJ/PLY) with --centrelines
  std::string centrelines;  // JSON or .pth for an imported mesh
  std::string patient = "default";
  double unit_mm = 1.0;  // file units of an imported mesh, in mm
  bool no_cache = false;
  std::string cache_dir;
};

std::string lower_ext(const std::string& path) {
  std::string e = std::filesystem::path(path).extension().string();
  std::transform(e.begin(), e.end(), e.begin(), [](unsigned char c) { return std::tolower(c); });
  return e;
}

struct Loaded {
  VesselTree tree;
  Lumen lumen;
};

Loaded load(const Source& s) {
  Loaded l;
  const std::string ext = s.file.empty() ? "" : lower_ext(s.file);
  if (ext == ".stl" || ext == ".obj" || ext == ".ply") {
    if (s.centrelines.empty())
      throw InputError("anatomy", "--centrelines", "an imported mesh needs its centrelines file");
    l.tree = load_mesh_centrelines(s.centrelines, s.file, s.unit_mm * 1e-3);
    l.lumen = import_lumen(s.file, l.tree, s.unit_mm * 1e-3);
    return l;
  }
  if (!s.file.empty() && ext != ".json")
    throw InputError(s.file, "file", "expected an anatomy .json or a lumen .stl, .obj or .ply");
  l.tree = s.file.empty()
               ? default_patient(patient_variant_from_string(s.patient, "anatomy --patient"))
               : load_vessel_tree(s.file);
  LumenSettings st;
  st.use_cache = !s.no_cache;
  st.cache_dir = s.cache_dir;
  l.lumen = build_lumen(l.tree, st);
  return l;
}

nlohmann::json describe(const Loaded& l) {
  const LumenCheck c = check_lumen(l.lumen.mesh, l.lumen.ends);
  nlohmann::json segs = nlohmann::json::array();
  for (int i = 0; i < l.tree.num_segments(); ++i) {
    const VesselSegment& s = l.tree.segments[i];
    double lo = 1e300, hi = 0.0, mean = 0.0;
    for (double r : s.radii) {
      lo = std::min(lo, r);
      hi = std::max(hi, r);
      mean += r / static_cast<double>(s.radii.size());
    }
    segs.push_back({{"name", s.name},
                    {"kind", std::string(to_string(s.kind))},
                    {"parent", s.parent < 0 ? nlohmann::json(nullptr)
                                            : nlohmann::json(l.tree.segments[s.parent].name)},
                    {"length_mm", segment_length(s) * 1e3},
                    {"ostium_mm", ostium_distance(l.tree, i) * 1e3},
                    {"radius_min_mm", lo * 1e3},
                    {"radius_max_mm", hi * 1e3},
                    {"radius_mean_mm", mean * 1e3}});
  }
  nlohmann::json les = nlohmann::json::array();
  for (const Lesion& le : l.tree.lesions)
    les.push_back({{"segment", l.tree.segments[le.segment].name},
                   {"distance_mm", le.distance * 1e3},
                   {"length_mm", le.length * 1e3},
                   {"diameter_reduction_percent", le.diameter_reduction * 100.0}});
  return {{"name", l.tree.name},
          {"coordinates", "LPS"},
          {"triangles", c.triangles},
          {"vertices", c.vertices},
          {"watertight", c.watertight},
          {"manifold", c.manifold},
          {"open_ends", c.open_ends},
          {"boundary_loops", c.boundary_loops},
          {"unmatched_loops", c.unmatched_loops},
          {"non_manifold_edges", c.non_manifold_edges},
          {"non_manifold_vertices", c.non_manifold_vertices},
          {"components", c.components},
          {"build_seconds", l.lumen.build_seconds},
          {"cache", l.lumen.cache_status},
          {"segments", segs},
          {"lesions", les}};
}

void add_source(CLI::App* cmd, Source& s) {
  cmd->add_option("file", s.file,
                  "Anatomy JSON, or a lumen mesh (.stl/.obj/.ply) with --centrelines "
                  "(default: the built-in patient)");
  cmd->add_option("--patient", s.patient, "Built-in patient: default, left-dominant");
  cmd->add_option("--centrelines", s.centrelines, "Centrelines of an imported mesh (.json, .pth)");
  cmd->add_option("--unit-mm", s.unit_mm,
                  "Units of an imported mesh and .pth paths, in mm (default 1; 10 for cm)");
  cmd->add_flag("--no-cache", s.no_cache, "Rebuild the lumen without the cache");
  cmd->add_option("--cache-dir", s.cache_dir, "Lumen cache directory");
}

int cmd_info(const Source& s, bool json) {
  const Loaded l = load(s);
  const nlohmann::json j = describe(l);
  if (json) {
    std::cout << j.dump(2) << "\n";
    return 0;
  }
  std::cout
      << "anatomy " << j["name"].get<std::string>() << " (LPS): " << j["triangles"]
      << " triangles, watertight " << (j["watertight"].get<bool>() ? "yes" : "no") << " ("
      << j["boundary_loops"] << " loops at " << j["open_ends"] << " open ends), manifold "
      << (j["manifold"].get<bool>() ? "yes" : "no") << ", built in " << j["build_seconds"]
      << " s (cache " << j["cache"].get<std::string>()
      << ")\n\n| segment | kind | parent | length (mm) | radius (mm) |\n|---|---|---|---|---|\n";
  for (const auto& sg : j["segments"]) {
    char r[64];
    std::snprintf(r, sizeof r, "%.2f-%.2f", sg["radius_min_mm"].get<double>(),
                  sg["radius_max_mm"].get<double>());
    char len[32];
    std::snprintf(len, sizeof len, "%.1f", sg["length_mm"].get<double>());
    std::cout << "| " << sg["name"].get<std::string>() << " | " << sg["kind"].get<std::string>()
              << " | " << (sg["parent"].is_null() ? "-" : sg["parent"].get<std::string>()) << " | "
              << len << " | " << r << " |\n";
  }
  return 0;
}

int cmd_build(const Source& s, bool json) {
  const Loaded l = load(s);
  const LumenCheck c = check_lumen(l.lumen.mesh, l.lumen.ends);
  if (json) {
    std::cout << nlohmann::json{{"triangles", c.triangles},
                                {"watertight", c.watertight},
                                {"manifold", c.manifold},
                                {"build_seconds", l.lumen.build_seconds},
                                {"cache", l.lumen.cache_status}}
                     .dump(2)
              << "\n";
  } else {
    std::cout << "lumen of " << l.tree.name << ": " << c.triangles << " triangles in "
              << l.lumen.build_seconds << " s (cache " << l.lumen.cache_status << ")\n";
  }
  return c.watertight && c.manifold ? 0 : 1;
}

int cmd_export(const Source& s, const std::string& out, bool healthy, bool body) {
  const std::string ext = lower_ext(out);
  if (ext != ".stl" && ext != ".obj" && ext != ".json")
    throw InputError("anatomy export", "--out", "expected a .stl, .obj or .json path");
  if (ext == ".json") {
    const VesselTree t =
        s.file.empty() || lower_ext(s.file) == ".json"
            ? (s.file.empty()
                   ? default_patient(patient_variant_from_string(s.patient, "anatomy --patient"))
                   : load_vessel_tree(s.file))
            : load_mesh_centrelines(s.centrelines, s.file, s.unit_mm * 1e-3);
    save_vessel_tree(t, out);
    std::cout << "wrote " << out << "\n";
    return 0;
  }
  Loaded l = load(s);
  TriangleMesh m = l.lumen.mesh;
  if (healthy) {
    m.vertices = l.lumen.healthy_vertices;
    m.recompute_normals();
  }
  auto write = [&](const TriangleMesh& mesh, const std::string& path) {
    if (ext == ".stl")
      write_stl(mesh, path, true, 1e-3);
    else
      write_obj(mesh, path, 1e-3);
    std::cout << "wrote " << path << " (" << mesh.num_triangles() << " triangles, mm)\n";
  };
  write(m, out);
  if (body) {
    const std::filesystem::path p(out);
    for (const BodyPart& part : build_body_context(l.tree)) {
      const auto path = p.parent_path() / (p.stem().string() + "_" + part.name + ext);
      write(part.mesh, path.string());
    }
  }
  return 0;
}

// ---- bench anatomy

struct BenchOptions {
  int steps = 20000;
  int warmup = 1000;
  int patch_triangles = BeatingLumenSettings{}.patch_triangles;
  double node_spacing_mm = 2.0;
  bool respiration = false;
  bool json = false;
  std::string patient = "default";
};

double median(std::vector<double> v) {
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
  return v[v.size() / 2];
}

int bench_anatomy(const BenchOptions& o) {
  if (o.steps < 10) throw InputError("bench anatomy", "--steps", "expected at least 10");
  require_in_range(o.node_spacing_mm, 0.1, 50.0, "bench anatomy", "--node-spacing-mm");
  const VesselTree tree = default_patient(patient_variant_from_string(o.patient, "bench anatomy"));
  const Lumen lu = build_lumen(tree);
  MotionSettings ms;
  ms.respiration = o.respiration;
  const CardiacMotion motion(tree, ms);
  BeatingLumenSettings bs;
  bs.patch_triangles = o.patch_triangles;
  BeatingLumen beating(lu.mesh, motion, bs);
  // Instruments from the femoral access to the lesion: a 6F guide catheter (r 1 mm) up to the
  // left main ostium, a 0.014" wire (r 0.178 mm) beyond; every node pressed against the nearest
  // wall (the worst case for contacts), at rest positions.
  const auto path = route(tree, tree.access, tree.target, o.node_spacing_mm * 1e-3);
  AabbTree full;
  full.build(lu.mesh);
  std::vector<Vec3> nodes;
  std::vector<double> radii;
  bool wire = false;
  for (const Vec3& p : path) {
    const SphereContact c = full.query_sphere(lu.mesh, p, 0.05);
    const int seg = c.triangle >= 0 ? lu.triangle_segment[c.triangle] : 0;
    wire = wire || tree.segments[seg].kind == VesselKind::kCoronary;
    const double r = wire ? 0.178e-3 : 1.0e-3;
    const Vec3 n = c.touching ? Vec3((c.point - p).normalized()) : Vec3::Zero();
    nodes.push_back(c.touching ? Vec3(c.point - (r - 0.05e-3) * n) : p);
    radii.push_back(r);
  }
  const double dt = 1e-3;
  std::vector<double> us, tris, patches;
  std::vector<SphereContact> contacts(nodes.size());
  std::vector<double> query_us;
  for (int k = 0; k < o.warmup + o.steps; ++k) {
    const BeatingLumenProfile p = beating.update(k * dt, nodes, radii);
    if (k >= o.warmup) {
      us.push_back(p.us);
      tris.push_back(p.triangles_updated);
      patches.push_back(p.patches_updated);
    }
    if (k >= o.warmup && k % 50 == 0) {
      const double t0 = now_us();
      beating.query_spheres(nodes, radii, contacts);
      query_us.push_back(now_us() - t0);
    }
  }
  const BeatingLumenProfile all = beating.update_all(0.4321);
  nlohmann::json j = {
      {"patient", tree.name},
      {"triangles", lu.mesh.num_triangles()},
      {"patches", beating.num_patches()},
      {"static_triangles", beating.num_static_triangles()},
      {"nodes", nodes.size()},
      {"steps", o.steps},
      {"dt_s", dt},
      {"respiration", o.respiration},
      {"step_us_median", median(us)},
      {"step_us_p95",
       [&] {
         auto v = us;
         std::sort(v.begin(), v.end());
         return v[v.size() * 95 / 100];
       }()},
      {"triangles_updated_median", median(tris)},
      {"patches_updated_median", median(patches)},
      {"update_all_us", all.us},
      {"update_all_triangles", all.triangles_updated},
      {"query_us_median", median(query_us)},
  };
  if (o.json) {
    std::cout << j.dump(2) << "\n";
  } else {
    std::cout
        << "| triangles | nodes | step (us, median) | p95 | triangles moved | all moving (us) |"
           " query (us) |\n|---|---|---|---|---|---|---|\n| "
        << j["triangles"] << " | " << j["nodes"] << " | " << j["step_us_median"] << " | "
        << j["step_us_p95"] << " | " << j["triangles_updated_median"] << " | " << j["update_all_us"]
        << " | " << j["query_us_median"] << " |\n";
  }
  return 0;
}

struct CentrelineOptions {
  std::string mesh;
  std::vector<double> inlet_mm;
  double unit_mm = 1.0;
  double band_mm = 0.0;
  std::string out;
  std::string compare;
};

// Distance from each point of `a`'s centrelines (resampled every 0.5 mm) to the nearest point of
// `b`'s: the median and 95th percentile (m).
std::pair<double, double> centreline_distance(const VesselTree& a, const VesselTree& b) {
  std::vector<Vec3> ref;
  for (const VesselSegment& s : b.segments) {
    const double len = segment_length(s);
    for (double t = 0.0; t <= len; t += 0.25e-3) ref.push_back(point_at(s, t));
  }
  std::vector<double> d;
  for (const VesselSegment& s : a.segments) {
    const double len = segment_length(s);
    for (double t = 0.0; t <= len; t += 0.5e-3) {
      const Vec3 p = point_at(s, t);
      double best = 1e9;
      for (const Vec3& q : ref) best = std::min(best, (p - q).squaredNorm());
      d.push_back(std::sqrt(best));
    }
  }
  if (d.empty()) return {0.0, 0.0};
  std::sort(d.begin(), d.end());
  return {d[d.size() / 2], d[std::min(d.size() - 1, d.size() * 95 / 100)]};
}

int cmd_centrelines(const CentrelineOptions& o) {
  if (o.inlet_mm.size() != 3)
    throw InputError("anatomy centrelines", "--inlet-mm", "expected three numbers x y z (mm)");
  if (!(o.unit_mm > 0.0)) throw InputError("anatomy centrelines", "--unit-mm", "expected > 0");
  MeshLoadOptions mo;
  mo.unit_scale = o.unit_mm * 1e-3;
  const TriangleMesh mesh = load_mesh(o.mesh, mo);
  const Vec3 inlet(o.inlet_mm[0] * kMm, o.inlet_mm[1] * kMm, o.inlet_mm[2] * kMm);
  const double t0 = now_us();
  const VesselTree tree = centrelines_from_mesh(mesh, inlet, o.mesh, o.band_mm * kMm);
  const double secs = (now_us() - t0) * 1e-6;
  std::cout << "centrelines of " << o.mesh << ": " << tree.num_segments() << " segments in " << secs
            << " s\n";
  for (const VesselSegment& s : tree.segments)
    std::cout << "  " << s.name << " (parent "
              << (s.parent >= 0 ? tree.segments[s.parent].name : "-")
              << "): " << segment_length(s) * 1e3 << " mm, radius "
              << *std::min_element(s.radii.begin(), s.radii.end()) * 1e3 << "-"
              << *std::max_element(s.radii.begin(), s.radii.end()) * 1e3 << " mm\n";
  if (!o.compare.empty()) {
    const VesselTree ref = load_vessel_tree(o.compare);
    const auto [median, p95] = centreline_distance(tree, ref);
    std::cout << "  against " << o.compare << ": distance to its centrelines median "
              << median * 1e3 << " mm, 95th percentile " << p95 * 1e3 << " mm\n";
  }
  if (!o.out.empty()) {
    save_vessel_tree(tree, o.out);
    std::cout << "wrote " << o.out << "\n";
  }
  return 0;
}

// `vcsim anatomy repair IN OUT`: a mesh with small defects (non-manifold edges, degenerate or
// duplicate triangles, loose pieces) made one the engine accepts, in the input's unit.
int cmd_repair(const std::string& in, const std::string& out, double min_component) {
  const std::string ext = lower_ext(out);
  if (ext != ".stl" && ext != ".obj" && ext != ".ply")
    throw InputError("anatomy repair", "OUT", "expected a .stl, .obj or .ply path, got " + out);
  if (!(min_component >= 0.0 && min_component < 1.0))
    throw InputError("anatomy repair", "--min-component", "expected a fraction in [0, 1)");
  MeshLoadOptions mo;
  mo.check = false;
  TriangleMesh mesh = load_mesh(in, mo);
  MeshRepairSettings settings;
  settings.min_component_fraction = min_component;
  const MeshRepairReport rr = repair_mesh(mesh, in, settings);
  const MeshReport cr = check_and_repair(mesh, in);  // the engine's own check, as on load
  // The mesh is in the file's unit here: MeshReport's volumes, printed in m^3, are in its cube.
  std::string check = cr.summary();
  for (std::size_t k; (k = check.find(" m^3")) != std::string::npos;)
    check.replace(k, 4, " (the file's unit)^3");
  std::cout << "repaired " << in << ":\n" << rr.summary() << "then:\n" << check;
  if (ext == ".stl")
    write_stl(mesh, out, true);
  else if (ext == ".obj")
    write_obj(mesh, out);
  else
    write_ply(mesh, out);
  std::cout << "wrote " << out << " (" << mesh.num_triangles() << " triangles, the input's unit)\n";
  return 0;
}

void install(CLI::App& app, int& status) {
  auto* an = app.add_subcommand("anatomy", "Patient anatomy: vessel tree and lumen mesh");
  an->require_subcommand(1);

  auto info_src = std::make_shared<Source>();
  auto info_json = std::make_shared<bool>(false);
  auto* info = an->add_subcommand("info", "Describe an anatomy (default: the built-in patient)");
  add_source(info, *info_src);
  info->add_flag("--json", *info_json, "Print JSON");
  info->callback([info_src, info_json, &status] { status = cmd_info(*info_src, *info_json); });

  auto build_src = std::make_shared<Source>();
  auto build_json = std::make_shared<bool>(false);
  auto* build = an->add_subcommand("build", "Build (and cache) the lumen mesh");
  add_source(build, *build_src);
  build->add_flag("--json", *build_json, "Print JSON");
  build->callback(
      [build_src, build_json, &status] { status = cmd_build(*build_src, *build_json); });

  auto ex_src = std::make_shared<Source>();
  auto ex_out = std::make_shared<std::string>();
  auto ex_healthy = std::make_shared<bool>(false);
  auto ex_body = std::make_shared<bool>(false);
  auto* ex =
      an->add_subcommand("export", "Write the lumen (.stl, .obj, in mm) or the tree (.json)");
  add_source(ex, *ex_src);
  ex->add_option("--out,-o", *ex_out, "Output path (.stl, .obj or .json)")->required();
  ex->add_flag("--healthy", *ex_healthy, "The lumen without lesions");
  ex->add_flag("--body", *ex_body, "Also write the body context meshes beside it");
  ex->callback([ex_src, ex_out, ex_healthy, ex_body, &status] {
    status = cmd_export(*ex_src, *ex_out, *ex_healthy, *ex_body);
  });

  auto co = std::make_shared<CentrelineOptions>();
  auto* ce = an->add_subcommand(
      "centrelines", "Compute centrelines from a lumen mesh (geodesic level sets), as a tree JSON");
  ce->add_option("mesh", co->mesh, "Lumen mesh (.stl, .obj, .ply)")->required();
  ce->add_option("--inlet-mm", co->inlet_mm, "A point near the inlet's opening: x y z (mm)")
      ->expected(3)
      ->required();
  ce->add_option("--unit-mm", co->unit_mm, "The mesh file's unit in mm (default 1)");
  ce->add_option("--band-mm", co->band_mm, "Width of the level-set bands (default: automatic)");
  ce->add_option("--out,-o", co->out, "Write the tree (.json)");
  ce->add_option("--compare", co->compare,
                 "A tree JSON to compare with (median and 95th percentile distance)");
  ce->callback([co, &status] { status = cmd_centrelines(*co); });

  auto rp_in = std::make_shared<std::string>();
  auto rp_out = std::make_shared<std::string>();
  auto rp_min = std::make_shared<double>(MeshRepairSettings{}.min_component_fraction);
  auto* rp = an->add_subcommand(
      "repair", "Repair a mesh with small defects (non-manifold edges, loose pieces) for import");
  rp->add_option("in", *rp_in, "Mesh to repair (.stl, .obj, .ply)")->required();
  rp->add_option("out", *rp_out, "Repaired mesh (.stl, .obj or .ply, same unit)")->required();
  rp->add_option("--min-component", *rp_min,
                 "Drop pieces with fewer triangles than this fraction of the largest (0.01)");
  rp->callback([rp_in, rp_out, rp_min, &status] { status = cmd_repair(*rp_in, *rp_out, *rp_min); });

  auto bo = std::make_shared<BenchOptions>();
  auto* b = bench_group(app).add_subcommand(
      "anatomy", "Per-step cost of cardiac motion (vertex update + refit of touched patches)");
  b->add_option("--steps", bo->steps, "Timed steps (1 kHz)");
  b->add_option("--patch-triangles", bo->patch_triangles, "Triangles per patch");
  b->add_option("--node-spacing-mm", bo->node_spacing_mm, "Instrument node spacing (mm)");
  b->add_option("--patient", bo->patient, "default, left-dominant");
  b->add_flag("--respiration", bo->respiration, "Add respiratory motion");
  b->add_flag("--json", bo->json, "Print JSON");
  b->callback([bo, &status] { status = bench_anatomy(*bo); });
}

const int kRegistered = register_command(30, install);

}  // namespace

}  // namespace vcsim::app
