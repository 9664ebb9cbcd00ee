// The solver tests' scene: a solver model of one or more instruments, its state and workspace,
// stepped by solver_step. Tests may change the settings from step to step (step(wall, settings,
// command) puts them in the model first); a simulation never does.
#pragma once

#include <span>
#include <utility>
#include <vector>

#include "vcsim/solver.h"

namespace vcsim::test {

struct Rig {
  SolverModel model;
  SolverState state;
  SolverWorkspace ws;

  Rig(std::vector<InstrumentModel> instruments, std::vector<InstrumentState> states,
      const SolverSettings& settings = {}, std::vector<CouplingModel> couplings = {})
      : model(make_model(std::move(instruments), settings, std::move(couplings))),
        state(make_solver_state(model, std::move(states))),
        ws(model) {}

  StepInfo step(VesselWall* wall, std::span<const DriveCommand> commands,
                StepProfile* profile = nullptr) {
    return solver_step(model, state, ws, wall, commands, profile);
  }
  StepInfo step(VesselWall* wall, const DriveCommand& command, StepProfile* profile = nullptr) {
    return step(wall, std::span<const DriveCommand>(&command, 1), profile);
  }
  // With these settings from now on (one split).
  StepInfo step(VesselWall* wall, const SolverSettings& settings, const DriveCommand& command,
                StepProfile* profile = nullptr) {
    model.settings.assign(1, settings);
    return step(wall, command, profile);
  }
  StepInfo step(VesselWall* wall, const SolverSettings& settings,
                std::span<const DriveCommand> commands, StepProfile* profile = nullptr) {
    model.settings.assign(1, settings);
    return step(wall, commands, profile);
  }

  SolverSettings& settings() { return model.settings[0]; }
  const RodModel& md(int i = 0) const { return model.instruments[i].rod(); }
  RodState& rod(int i = 0) { return state.instruments[i].rod; }
  const RodState& rod(int i = 0) const { return state.instruments[i].rod; }
  DriveState& drive(int i = 0) { return state.instruments[i].drive; }
  const DriveState& drive(int i = 0) const { return state.instruments[i].drive; }
  std::span<const NodeContact> contacts(int i = 0) const { return ws.contacts(i); }

 private:
  static SolverModel make_model(std::vector<InstrumentModel> instruments,
                                const SolverSettings& settings,
                                std::vector<CouplingModel> couplings) {
    SolverModel m;
    m.instruments = std::move(instruments);
    m.couplings = std::move(couplings);
    m.settings = {settings};
    return m;
  }
};

// One instrument driven through `sheath` with `depth` (m) inserted.
inline Rig driven(const RodDef& def, const Sheath& sheath, const ContactMaterial& contact,
                  double depth, double roll = 0.0) {
  InstrumentModel im = make_instrument_model(def, sheath, contact);
  InstrumentState st = make_instrument_state(im, depth, roll);
  std::vector<InstrumentModel> ims;
  ims.push_back(std::move(im));
  std::vector<InstrumentState> sts;
  sts.push_back(std::move(st));
  return Rig(std::move(ims), std::move(sts));
}

// One free rod (no drive) in the shape its definition gives. The settings at construction size
// the workspace (SolverSettings::edge_sample_spacing).
inline Rig free_rod_rig(const RodDef& def, const ContactMaterial& contact,
                        const SolverSettings& settings = {}) {
  InstrumentModel im = make_free_instrument_model(def, contact);
  InstrumentState st = make_free_instrument_state(im, def);
  std::vector<InstrumentModel> ims;
  ims.push_back(std::move(im));
  std::vector<InstrumentState> sts;
  sts.push_back(std::move(st));
  return Rig(std::move(ims), std::move(sts), settings);
}

}  // namespace vcsim::test
