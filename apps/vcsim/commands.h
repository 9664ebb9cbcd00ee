// Subcommands of the vcsim command line (each returns the process exit status).
#pragma once

#include <string>

#include "vcsim/rod.h"

namespace vcsim::app {

struct RodBenchOptions {
  int nodes = 256;
  int steps = 20000;
  int warmup = 2000;
  int iterations = 1;
  DistanceMethod method = DistanceMethod::kGlobal;
  bool json = false;
};

int bench_rod(const RodBenchOptions& opt);

}  // namespace vcsim::app
