// Experiments of the VCSim3 paper re-run on vcsim (docs/validation.md).
#pragma once

#include <string>
#include <vector>

#include "vcsim/solver.h"

namespace vcsim {

// The compression experiment (paper Table 1, Fig. 9): a 255 mm rod of 256 mass points is pushed
// through a straight tube into a 90 degree bend that ends blind, and pushed on after its tip is
// stopped; compression = (rest length - centreline arc length) / rest length.
struct CompressionOptions {
  int nodes = 256;
  double rod_length = 0.255;       // m
  double outer_radius = 0.665e-3;  // m (4F polymer shaft, clinical.md)
  double inner_radius = 0.4e-3;    // m
  double youngs_modulus = 170e6;   // Pa (polymer catheter body, clinical.md)
  double density = 1100;           // kg/m^3
  double lumen_radius = 2.5e-3;    // m
  double straight1 = 0.200;        // m, access to the bend
  double bend_radius = 0.015;      // m, centreline of the bend
  double bend_angle_deg = 90;
  double straight2 = 0.010;    // m, after the bend, then a blind end
  double dt = 1e-3;            // s; 0 = the stable step at the physical density
  double push_speed = 0.05;    // m/s
  double start_depth = 0.190;  // m inserted at the start (tip just before the bend)
  double end_depth = 0.250;    // m inserted at the end of the push
  double settle_time = 0.2;    // s held at the end depth before measuring
  double mu = 0.1;             // instrument-vessel friction (clinical.md)
  void validate(const std::string& source) const;
};

struct CompressionRow {
  std::string method;
  int iterations = 1;
  double compression_percent = 0.0;      // at the end of the push
  double max_compression_percent = 0.0;  // worst during the run
  double constraints_us = 0.0;           // median per step: distance + contact iterations
  double step_us = 0.0;                  // median per step
  double forces_us = 0, integration_us = 0, collision_us = 0, distance_us = 0, contacts_us = 0;
  double axial_force = 0.0;  // N at the hand at the end
  int contacts = 0;          // contacts at the end
  double max_outside = 0.0;  // worst node escape beyond the wall, over its radius
  double dt = 0.0;
  double mass_scale = 1.0;
  double penalty_modulus_scale = 1.0;
};

// The scene: the bent blind tube (mesh + tree) and the rod on its sheath (one instrument).
struct CompressionScene {
  TriangleMesh mesh;
  AabbTree tree;
  SolverModel model;
  SolverState state;
  double mass_scale = 1.0;
  StaticWall wall() const { return StaticWall(mesh, tree); }
};
CompressionScene make_compression_scene(const CompressionOptions& opt, DistanceMethod method,
                                        int iterations);
// The experiment's schedule: how many steps of `dt` the push and the settling take, and the
// inserted depth commanded at step k = 1, 2, ... (pushed at push_speed, then held).
long long compression_steps(const CompressionOptions& opt, double dt);
double compression_depth(const CompressionOptions& opt, long long k, double dt);
CompressionRow run_compression(const CompressionOptions& opt, DistanceMethod method,
                               int iterations);
// The rows of the paper's Table 1 (method, iterations).
std::vector<std::pair<DistanceMethod, int>> compression_table_rows();

// Distance from a point to the tube's centreline polyline minus the lumen radius (> 0: outside).
double outside_tube(const std::vector<Vec3>& centreline, double radius, const Vec3& p);

}  // namespace vcsim

namespace vcsim {

// A guidewire inside a catheter, both from the catalogue, entering one sheath into a bent
// vessel (paper Fig. 10 set-up). Runs at dt with quasi-static mass scaling like the compression
// experiment.
struct PairOptions {
  std::string wire = "wire-035-stiff-exchange";
  std::string catheter = "catheter-jl4-6f";
  int nodes = 512;               // per instrument (at most)
  double dt = 1e-3;              // s
  double lumen_radius = 4e-3;    // m
  double catheter_depth = 0.26;  // m inserted at the start
  double wire_depth = 0.29;      // m inserted at the start (ahead of the catheter tip)
  bool collisions = true;
  bool gravity = false;
  std::string catalogue_dir;  // empty: the default catalogue
  void validate(const std::string& source) const;
};

struct PairScene {
  TriangleMesh mesh;
  AabbTree tree;
  SolverModel model;  // instruments [0] wire, [1] catheter; couplings [0] the wire in the catheter
  SolverState state;
  StaticWall wall() const { return StaticWall(mesh, tree); }
};
PairScene make_pair_scene(const PairOptions& opt);

}  // namespace vcsim
