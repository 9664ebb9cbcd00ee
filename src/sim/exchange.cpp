// Instrument exchange in a running simulation (docs/scenarios.md, "Instrument exchange";
// docs/architecture.md): the rules a change must keep, the model rebuilt around the same anatomy
// (model.cpp) and the state carried over to it.
#include <cmath>
#include <cstdio>

#include "vcsim/sim.h"

namespace vcsim {

namespace {

std::string mm(double m) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.1f mm", m * 1e3);
  return buf;
}

// (instrument of `to`) its index in `from`, -1 for one added.
std::vector<int> kept_from(const SimModel& from, const SimModel& to) {
  std::vector<int> was(static_cast<std::size_t>(to.num_instruments()), -1);
  for (int j = 0; j < to.num_instruments(); ++j)
    was[static_cast<std::size_t>(j)] = from.instrument_index(to.instrument_name(j));
  return was;
}

}  // namespace

SimState carry_sim_state(const SimModel& from, const SimState& st, const SimModel& to) {
  const std::vector<int> was = kept_from(from, to);
  const std::size_t n = was.size();
  std::vector<InstrumentState> insts;
  insts.reserve(n);
  for (std::size_t j = 0; j < n; ++j)
    insts.push_back(was[j] >= 0 ? st.solver.instruments[static_cast<std::size_t>(was[j])]
                                : make_instrument_state(to.solver.instruments[j], 0.0));
  SimState out;
  out.solver = make_solver_state(to.solver, std::move(insts));
  out.solver.time = st.solver.time;
  out.solver.split = st.solver.split;
  out.solver.hold_until = st.solver.hold_until;
  out.solver.held_split = st.solver.held_split;
  out.contrast = st.contrast;
  // Metrics: run totals as they are, an instrument's by its name (an added one starts afresh).
  out.metrics = st.metrics;
  auto by_name = [&]<class T>(const std::vector<T>& v, T fresh) {
    std::vector<T> r(n, fresh);
    for (std::size_t j = 0; j < n; ++j)
      if (was[j] >= 0) r[j] = v[static_cast<std::size_t>(was[j])];
    return r;
  };
  SimMetrics& m = out.metrics;
  m.tip_path = by_name(st.metrics.tip_path, 0.0);
  m.peak_wall_force = by_name(st.metrics.peak_wall_force, 0.0);
  m.peak_axial_force = by_name(st.metrics.peak_axial_force, 0.0);
  m.peak_axial_jump = by_name(st.metrics.peak_axial_jump, 0.0);
  m.peak_torque = by_name(st.metrics.peak_torque, 0.0);
  m.last_axial_force = by_name(st.metrics.last_axial_force, std::nan(""));
  m.escapes = by_name(st.metrics.escapes, EscapeRecord{});
  m.edge_crossings = by_name(st.metrics.edge_crossings, EscapeRecord{});
  // The procedure as it is (balloons keep their indices); an added balloon's state after them.
  out.procedure = st.procedure;
  extend_procedure_state(to.procedure, out.procedure, out.solver);
  out.random = st.random;
  return out;
}

void Simulator::change_instruments(std::vector<ScenarioInstrument> list, const std::string& src,
                                   const std::function<std::string(int)>& field_of_in) {
  const SimModel& old = *model_;
  const std::function<std::string(int)> field_of = [&](int i) {
    if (field_of_in) return field_of_in(i);
    return i < 0 ? std::string("instruments") : "instruments[" + std::to_string(i) + "]";
  };
  if (list.empty())
    throw InputError(src, field_of(-1), "expected at least one instrument left in the scene");
  // A kept instrument is the same rod: its state goes on unchanged.
  for (std::size_t j = 0; j < list.size(); ++j) {
    const int i = old.instrument_index(list[j].name);
    // (a name given twice is validate_instruments' to report)
    if (i < 0 || find_instrument_in(std::span(list).first(j), list[j].name) >= 0) continue;
    const ScenarioInstrument& now = old.scenario.instruments[static_cast<std::size_t>(i)];
    const int jj = static_cast<int>(j);
    if (now.catalogue != list[j].catalogue)
      throw InputError(src, field_of(jj) + ".catalogue",
                       "expected '" + now.catalogue + "', the catalogue entry of '" + now.name +
                           "' in the scene (another instrument needs another name), got '" +
                           list[j].catalogue + "'");
    if (now.max_nodes != list[j].max_nodes || now.tip_segment != list[j].tip_segment)
      throw InputError(src, field_of(jj),
                       "expected the max_nodes and tip_segment_mm of '" + now.name +
                           "' in the scene (the same rod)");
  }
  // A removed instrument is outside the patient, and nothing stays inside it or rides on it.
  for (int i = 0; i < old.num_instruments(); ++i) {
    const std::string& name = old.instrument_name(i);
    if (find_instrument_in(list, name) >= 0) continue;
    const double depth = state_.solver.instruments[static_cast<std::size_t>(i)].drive.depth;
    if (depth >= kWithdrawnDepth)
      throw InputError(src, field_of(-1),
                       "expected '" + name + "' outside the patient to remove it: withdraw it " +
                           "first (" + mm(depth) + " inserted)");
    for (const ScenarioInstrument& si : list)
      if (si.inside == name || si.over == name)
        throw InputError(src, field_of(-1),
                         "expected no instrument left " +
                             std::string(si.inside == name ? "inside '" : "over '") + name +
                             "' to remove it: '" + si.name +
                             "' is (remove that first, or declare it anew)");
  }
  std::shared_ptr<const SimModel> model = rebuild_sim_model(old, std::move(list), src, field_of);
  // (rebuild_sim_model checks the list: names, nesting, catalogue entries)
  SimState state = carry_sim_state(old, state_, *model);
  auto ws = std::make_unique<SimWorkspace>(*model, std::move(*ws_));
  model_ = std::move(model);
  state_ = std::move(state);
  state_.model = model_;
  ws_ = std::move(ws);
}

void Simulator::exchange(const InstrumentChange& change) {
  std::vector<ScenarioInstrument> list = model_->scenario.instruments;
  if (change.kind == InstrumentChange::Kind::kAdd) {
    if (find_instrument_in(list, change.name) >= 0)
      throw InputError(change.source, change.field + ".name",
                       "expected a name not in the scene, got '" + change.name + "'");
    list.push_back(to_scenario_instrument(change));
  } else {
    const int r = find_instrument_in(list, change.name);
    if (r < 0) {
      std::string names;
      for (const ScenarioInstrument& si : list) names += (names.empty() ? "" : ", ") + si.name;
      throw InputError(
          change.source, change.field,
          "expected an instrument in the scene (" + names + "), got '" + change.name + "'");
    }
    list.erase(list.begin() + r);
  }
  change_instruments(std::move(list), change.source, [&](int) { return change.field; });
}

std::vector<std::string> Simulator::instrument_names() const {
  std::vector<std::string> names;
  for (const ScenarioInstrument& si : model_->scenario.instruments) names.push_back(si.name);
  return names;
}

}  // namespace vcsim
