// `vcsim report RUN_DIR`: a run's session report (one offline HTML file); `vcsim report compare
// RUN_DIR...`: progress over sessions; `vcsim report csv RUN_DIR...`: the metrics for a
// spreadsheet. The assess layer does the work (src/assess, docs/assessment.md); this is options.
#include <iostream>
#include <memory>
#include <string>
#include <vector>

#include "commands.h"
#include "vcsim/assess.h"
#include "vcsim/core.h"

namespace vcsim::app {

namespace {

namespace fs = std::filesystem;

struct ReportCliOptions {
  std::string run_dir;
  std::string out;
  std::vector<std::string> runs;
  std::string template_file;
};

std::vector<fs::path> paths(const std::vector<std::string>& v) {
  return {v.begin(), v.end()};
}

void install(CLI::App& app, int& status) {
  auto o = std::make_shared<ReportCliOptions>();
  auto* cmd = app.add_subcommand(
      "report", "A run's session report: RUN_DIR/report.html (timeline, plots, frames, metrics)");
  cmd->add_option("run_dir", o->run_dir, "Folder of a run (vcsim run --out, a trainer session)");
  cmd->add_option("--out", o->out, "HTML file to write (default: RUN_DIR/report.html)");
  cmd->add_option("--template", o->template_file, "Mustache page template (default: data/report)");
  cmd->callback([o, &status, cmd] {
    if (cmd->get_subcommands().empty()) {
      if (o->run_dir.empty()) throw InputError("report", "RUN_DIR", "expected the folder of a run");
      ReportOptions ro;
      ro.template_file = o->template_file;
      const double t0 = now_us();
      const fs::path html = write_report(o->run_dir, o->out, ro);
      std::cout << "report: " << html.string() << " (" << (now_us() - t0) * 1e-6 << " s)\n";
      status = 0;
    }
  });
  cmd->require_subcommand(0, 1);

  auto* cmp =
      cmd->add_subcommand("compare", "Progress over sessions: one HTML page, runs in order");
  cmp->add_option("runs", o->runs, "Run folders, oldest first")->required();
  cmp->add_option("--out", o->out, "HTML file to write (default: compare.html)");
  cmp->callback([o, &status] {
    const fs::path out = o->out.empty() ? fs::path("compare.html") : fs::path(o->out);
    const auto runs = paths(o->runs);
    write_compare_report(runs, out);
    std::cout << "report: " << out.string() << " (" << runs.size() << " runs)\n";
    status = 0;
  });

  auto* csv = cmd->add_subcommand("csv", "The runs' metrics as CSV, one row per run");
  csv->add_option("runs", o->runs, "Run folders")->required();
  csv->add_option("--out", o->out, "CSV file to write (default: metrics.csv)");
  csv->callback([o, &status] {
    const fs::path out = o->out.empty() ? fs::path("metrics.csv") : fs::path(o->out);
    const auto runs = paths(o->runs);
    write_metrics_csv(runs, out);
    std::cout << "report: " << out.string() << " (" << runs.size() << " runs)\n";
    status = 0;
  });
}

const int kRegistered = register_command(7, install);

}  // namespace

}  // namespace vcsim::app
