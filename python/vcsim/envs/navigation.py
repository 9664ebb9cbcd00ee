"""Navigation environments in Gymnasium's conventions (docs/python.md).

ArchNavigation: one wire from the descending aorta to a target in a supra-aortic branch (the
setting of stEVE's benchmark). CoronaryNavigation: a guiding catheter seated in a coronary
ostium and a 0.014" wire to a target in the LAD, LCx or RCA of the beating heart.

Each reset draws an episode from its seed: the anatomy (built-in patient, calibre, arch
elongation and tortuosity), the instruments, the target and the C-arm angle. An episode's start
(the scene built, the instruments brought to their start) is made once per distinct draw and kept
as a snapshot: a reset to a cached start restores it in well under a millisecond.
"""
from __future__ import annotations

import collections
import dataclasses
import math
import numbers

import numpy as np

from .. import _vcsim
from ._spaces import Box, Dict, Env

__all__ = ["ArchNavigation", "CoronaryNavigation", "Episode", "StartFailed"]


class StartFailed(RuntimeError):
    """An episode's start could not be made (the autopilot bringing the instruments there gave
    up); reset() draws another episode."""


@dataclasses.dataclass(frozen=True)
class Episode:
    """What a reset drew: everything that decides an episode's start and goal."""

    anatomy: str  # built-in patient
    variation: tuple  # sorted (key, value) pairs for Anatomy.vary
    instruments: tuple  # catalogue entries, in the scene's order
    target_segment: str
    target_distance: float  # m along the target segment from its first point
    primary_deg: float
    secondary_deg: float
    heart_rate_bpm: float = 0.0  # 0: no beating heart

    @property
    def start_key(self):
        """Episodes with the same start key share a start snapshot (the C-arm is not part of
        it; the target is, as the autopilot's plan in the scene leads to it)."""
        return (self.anatomy, self.variation, self.instruments, self.heart_rate_bpm,
                self.target_segment, self.target_distance)


class _Navigation(Env):
    """Common mechanics: control at control_hz through drive velocities, tracked tip points or
    fluoroscopy as observation, stEVE's reward terms, a cache of episode starts."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 7.5}

    # Reward terms of stEVE's navigation tasks: reaching the target, a cost per step, and the
    # decrease of the centreline path length from tip to target (per mm).
    REWARD_TARGET = 1.0
    REWARD_STEP = -0.005
    REWARD_PATH_PER_MM = 0.001

    def __init__(self, *, control_hz=7.5, max_steps=1000, target_tolerance=5e-3,
                 observation="tracking2d", tracking_points=3, tracking_spacing=2e-3,
                 image_size=128, velocity_limit=(0.05, math.pi), randomize=True,
                 start_cache=8, render_mode=None, dose=1e4, threads=0, max_redraws=20):
        if observation not in ("tracking2d", "tracking3d", "image"):
            raise ValueError("observation: expected 'tracking2d', 'tracking3d' or 'image', got "
                             f"{observation!r}")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode: expected None or 'rgb_array', got {render_mode!r}")
        for name, v, lo, hi in (("control_hz", control_hz, 0.5, 1000.0),
                                ("target_tolerance", target_tolerance, 1e-4, 0.05),
                                ("tracking_spacing", tracking_spacing, 1e-4, 0.05)):
            if not (lo <= float(v) <= hi):
                raise ValueError(f"{name}: expected {lo} to {hi}, got {v!r}")
        if int(threads) < 0:
            raise ValueError(f"threads: expected 0 (as many as allowed) or more, got {threads!r}")
        if int(max_steps) < 1 or int(tracking_points) < 1 or int(start_cache) < 1:
            raise ValueError("max_steps, tracking_points and start_cache: expected at least 1")
        if (isinstance(max_redraws, bool) or not isinstance(max_redraws, numbers.Integral)
                or max_redraws < 0):
            raise ValueError(f"max_redraws: expected an integer of 0 or more, got {max_redraws!r}")
        if len(velocity_limit) != 2 or min(velocity_limit) <= 0:
            raise ValueError("velocity_limit: expected (m/s, rad/s), both > 0")
        self.control_hz = float(control_hz)
        self.max_steps = int(max_steps)
        self.target_tolerance = float(target_tolerance)
        self.observation = observation
        self.tracking_points = int(tracking_points)
        self.tracking_spacing = float(tracking_spacing)
        self.image_size = int(image_size)
        self.velocity_limit = (float(velocity_limit[0]), float(velocity_limit[1]))
        self.randomize = bool(randomize)
        self.start_cache = int(start_cache)
        # Draws thrown away in one reset before it gives up: a coronary LAD/LCx start seats in
        # a third to a half of its draws, so 5 left about one reset in 20 to 100 raising.
        self.max_redraws = int(max_redraws)
        self.render_mode = render_mode
        self.dose = float(dose)
        # The most threads a physics step may use (Simulator.threads); ThreadVectorEnv sets 1.
        self.threads = int(threads)
        self._starts = collections.OrderedDict()  # start_key -> (sim, snapshot, autopilot)
        self._fluoro = {}  # id(sim) -> Fluoroscopy
        self._failed = {}  # start_key -> why its start could not be made
        self._redraws = 0
        self.sim = None
        self.episode = None
        n = self.num_controlled
        hi = np.array([[self.velocity_limit[0], self.velocity_limit[1]]] * n, dtype=np.float32)
        self.action_space = Box(-hi, hi, dtype=np.float32)
        dim = 3 if observation == "tracking3d" else 2
        spaces = {
            "target": Box(-1.0, 1.0, shape=(dim,), dtype=np.float32),
            "last_action": Box(-hi, hi, dtype=np.float32),
        }
        if observation == "image":
            spaces["image"] = Box(0, 255, shape=(self.image_size, self.image_size),
                                  dtype=np.uint8)
        else:
            spaces["tracking"] = Box(-1.0, 1.0, shape=(n, self.tracking_points, dim),
                                     dtype=np.float32)
        self.observation_space = Dict(spaces)
        self._last_action = np.zeros((n, 2), dtype=np.float32)
        self._steps = 0
        self._path = 0.0

    # ---- what a task defines
    num_controlled = 1

    def _draw(self, rng: np.random.Generator) -> Episode:
        raise NotImplementedError

    def _build(self, ep: Episode):
        """(sim, autopilot at the episode's start) for a start key."""
        raise NotImplementedError

    def _tree(self, ep: Episode):
        """The episode's drawn anatomy (a cached tree of its own, never a simulator's
        `anatomy`: that view keeps its simulator alive, and a cache holding it would keep every
        start's simulator after the start cache has let it go)."""
        raise NotImplementedError

    # ---- Gymnasium API
    @property
    def control_steps(self) -> int:
        """Physics steps per control step."""
        return max(1, round(1.0 / (self.control_hz * self.sim.dt)))

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        options = options or {}
        given = options.get("episode")
        if given is not None and not isinstance(given, Episode):
            raise TypeError("options['episode']: expected a vcsim.envs.Episode")
        ep = given or self._draw(self.np_random)
        redraws = 0
        while ep.start_key not in self._starts:
            try:
                if ep.start_key in self._failed:
                    raise StartFailed(self._failed[ep.start_key])
                sim, pilot = self._build(ep)
            except StartFailed as e:
                # A drawn episode whose start could not be made (the autopilot that brings the
                # instruments there gave up): draw another from the same generator, so a seed
                # still decides the episode.
                self._failed[ep.start_key] = str(e)
                if given is not None:
                    raise
                if redraws >= self.max_redraws:
                    raise StartFailed(f"{type(self).__name__}: {redraws + 1} draws in a row "
                                      f"could not be started; the last: {e}") from e
                redraws += 1
                ep = self._draw(self.np_random)
                continue
            # The C-arm's isocentre with it: found from the centrelines, which take longer to
            # read than a restore does.
            self._starts[ep.start_key] = (sim, sim.snapshot(), pilot,
                                          self._isocentre(ep))
            while len(self._starts) > self.start_cache:
                _, old = self._starts.popitem(last=False)
                self._fluoro.pop(id(old[0]), None)
        key = ep.start_key
        self._starts.move_to_end(key)
        self._redraws = redraws
        sim, snap, pilot, isocentre = self._starts[key]
        sim.restore(snap)
        sim.threads = self.threads
        self.sim = sim
        self._start_autopilot = pilot
        self.episode = ep
        anatomy = self._anatomy = sim.anatomy
        self._target = anatomy.point_at(ep.target_segment, ep.target_distance)
        self._carm = _vcsim.CArm(primary_deg=ep.primary_deg, secondary_deg=ep.secondary_deg,
                                 fov=0.2 if not self._is_coronary else 0.15,
                                 isocentre=isocentre)
        self._last_action[:] = 0.0
        self._steps = 0
        self._path = self._path_length()
        return self._observe(), self._info(False)

    def step(self, action):
        self.sim.step(self._begin_step(action), steps=self.control_steps)
        return self._end_step()

    # step() in three parts, so that ThreadVectorEnv steps several simulators in one call
    # (vcsim.step_many) between the Python halves.
    def _begin_step(self, action):
        """Checks and clips an action; the simulator's action for it."""
        a = np.asarray(action, dtype=np.float64)
        if a.shape != self.action_space.shape:
            raise ValueError(f"action: expected shape {self.action_space.shape} "
                             f"(instrument, [translation m/s, rotation rad/s]), got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"action: expected finite values, got {a.tolist()}")
        if self.sim is None:
            raise RuntimeError("step() before reset()")
        a = np.clip(a, self.action_space.low, self.action_space.high)
        self._last_action[:] = a
        return self._full_action(a)

    def _end_step(self):
        """After the physics of a control step: (obs, reward, terminated, truncated, info)."""
        self._steps += 1
        path = self._path_length()
        gained = self._path - path
        self._path = path
        reached = self._reached()
        reward = (self.REWARD_STEP + self.REWARD_PATH_PER_MM * gained * 1e3
                  + (self.REWARD_TARGET if reached else 0.0))
        truncated = not reached and self._steps >= self.max_steps
        return self._observe(), float(reward), bool(reached), bool(truncated), self._info(reached)

    def render(self):
        if self.render_mode != "rgb_array" or self.sim is None:
            return None
        img = self._image()
        return np.repeat(img[:, :, None], 3, axis=2)

    def close(self):
        self._fluoro.clear()
        self._starts.clear()
        self.sim = None

    # ---- the autopilot as a baseline policy
    def autopilot(self):
        """The scenario's autopilot from this episode's start, as a policy: call it with an
        observation for an action (it reads the simulator as a trainee reads the screen)."""
        return _AutopilotBaseline(self)

    # ---- helpers
    _is_coronary = False

    def _full_action(self, a):
        return a

    def _controlled(self):
        return range(self.num_controlled)

    def _isocentre(self, ep):
        """Where the C-arm looks: the middle of the target vessel's centreline."""
        return _lines(self._tree(ep))[ep.target_segment]["points"].mean(axis=0)

    def _tip_rest(self):
        return self.sim.tip_rest(self._lead)

    @property
    def _lead(self):
        return self.sim.num_instruments - 1

    def _reached(self) -> bool:
        """The tip within target_tolerance of the target along the vessel: its place on the
        centreline (where the tip projects, a wire lying on the wall being a radius off the
        axis) that far from the target, and the tip inside the lumen."""
        _, _, outside = self.sim.tip_location(self._lead)
        return bool(self._path <= self.target_tolerance and outside < 1e-3)

    def _path_length(self) -> float:
        seg, dist, _ = self.sim.tip_location(self._lead)
        if not seg:
            return float(np.linalg.norm(self._tip_rest() - self._target))
        return self._anatomy.path_length(seg, dist, self.episode.target_segment,
                                   self.episode.target_distance)

    def _tracked(self, i, dim):
        """tracking_points points along instrument i from its tip back, tracking_spacing apart."""
        pts = self.sim.tracking(i, self.tracking_points, self.tracking_spacing)
        return self._carm.project(pts) if dim == 2 else pts

    def _observe(self):
        dim = 3 if self.observation == "tracking3d" else 2
        target = self._target if dim == 3 else self._carm.project(self._target[None, :])[0]
        obs = {"target": np.asarray(target - self._origin(dim), dtype=np.float32),
               "last_action": self._last_action.copy()}
        if self.observation == "image":
            obs["image"] = self._image()
        else:
            t = np.stack([self._tracked(i, dim) - self._origin(dim) for i in self._controlled()])
            obs["tracking"] = np.clip(t, -1.0, 1.0).astype(np.float32)
        return obs

    def _origin(self, dim):
        """Observations are relative to the C-arm's isocentre (3D) or the detector centre."""
        return self._carm.isocentre if dim == 3 else np.zeros(2)

    def _image(self):
        f = self._fluoro.get(id(self.sim))
        if f is None:
            f = _vcsim.Fluoroscopy(self.sim, size=self.image_size)
            self._fluoro[id(self.sim)] = f
        return f.image(self.sim, self._carm, dose=self.dose, seed=self._steps + 1)

    def _info(self, reached):
        return {"success": bool(reached), "path_length": float(self._path),
                "time": float(self.sim.time), "steps": self._steps,
                "target": (self.episode.target_segment, self.episode.target_distance),
                "target_point": self._target.copy(),
                "hand_forces": self.sim.hand_forces(), "episode": self.episode,
                "redraws": self._redraws}


class _AutopilotBaseline:
    """The autopilot run ahead over each control period on a copy of the state; the action is
    the mean drive velocity that takes each instrument where the autopilot would."""

    def __init__(self, env: _Navigation):
        self.env = env
        self.policy = _vcsim.AutopilotPolicy(env.sim, env._start_autopilot)
        self.period = 1.0 / env.control_hz

    def __call__(self, obs=None):
        a = self.policy.act(self.env.sim, self.period)
        return np.asarray(a[list(self.env._controlled())], dtype=np.float32)

    @property
    def failed(self) -> bool:
        """The autopilot gave up (stuck after every retry): it holds still from then on."""
        return self.policy.failed

    @property
    def status(self) -> str:
        return self.policy.status


def _uniform(rng, lo, hi, on=True):
    return float(rng.uniform(lo, hi)) if on else 0.5 * (lo + hi)


class ArchNavigation(_Navigation):
    """A 0.035" wire from the descending thoracic aorta to a target in a supra-aortic branch.

    Action: (1, 2) [translation m/s, rotation rad/s] at control_hz (7.5 Hz), limited to
    velocity_limit (50 mm/s, pi rad/s). Success: the tip within target_tolerance (5 mm) of the
    target along the vessel (its projection on the centreline). Episodes end at max_steps
    (1000). Randomised per reset (randomize=True): the arch (typical or elongated-tortuous
    built-in, arch elongation 0-25 mm, tortuosity 0-3 mm rms, aortic and branch calibre
    x0.85-1.15), the wire among `wires` (default: the angled hydrophilic 0.035" only), the target
    branch and depth (50-90 % of the branch) and the C-arm (LAO 20-50 deg, cranial -10-10 deg).
    """

    TARGETS = ("brachiocephalic", "left_common_carotid", "left_subclavian")
    WIRES = ("wire-035-angled-hydrophilic",)

    def __init__(self, *, targets=TARGETS, wires=WIRES, wire_nodes=96, dt=1e-3, **kw):
        targets = tuple(targets)
        wires = tuple(wires)
        if not targets or any(t not in self.TARGETS for t in targets):
            raise ValueError(f"targets: expected names among {self.TARGETS}, got {targets}")
        if not wires:
            raise ValueError("wires: expected at least one catalogue entry")
        if not (16 <= int(wire_nodes) <= 512):
            raise ValueError(f"wire_nodes: expected 16 to 512, got {wire_nodes}")
        if not (1e-4 <= float(dt) <= 2e-3):
            raise ValueError(f"dt: expected 1e-4 to 2e-3 s, got {dt}")
        self.targets = targets
        self.wires = wires
        self.wire_nodes = int(wire_nodes)
        self.dt = float(dt)
        super().__init__(**kw)

    def _draw(self, rng):
        r = self.randomize
        anatomy = "arch-tortuous" if (r and rng.uniform() < 0.3) else "arch"
        var = {
            "aorta_radius_scale": round(_uniform(rng, 0.85, 1.15, r), 3),
            "artery_radius_scale": round(_uniform(rng, 0.85, 1.15, r), 3),
            "arch_elongation": round(_uniform(rng, 0.0, 25e-3, r), 4) if r else 0.0,
            "tortuosity": round(_uniform(rng, 0.0, 3e-3, r), 4) if r else 0.0,
            "seed": int(rng.integers(1, 2**31)) if r else 1,
        }
        wire = self.wires[int(rng.integers(len(self.wires)))] if r else self.wires[0]
        target = self.targets[int(rng.integers(len(self.targets)))] if r else self.targets[0]
        frac = _uniform(rng, 0.5, 0.9, r)
        tree = _arch_tree(anatomy, tuple(sorted(var.items())))
        c = _lines(tree)[target]
        s0 = c["ostium_distance"]
        length = tree.segment_length(target)
        dist = round(s0 + frac * (length - s0), 4)
        return Episode(anatomy=anatomy, variation=tuple(sorted(var.items())),
                       instruments=(wire,), target_segment=target, target_distance=dist,
                       primary_deg=round(_uniform(rng, 20, 50, r), 1) if r else 35.0,
                       secondary_deg=round(_uniform(rng, -10, 10, r), 1) if r else 0.0)

    def _scenario(self, ep):
        goal = ep.target_distance - _ostium(self._tree(ep), ep.target_segment)
        return {
            "format": "vcsim-scenario", "version": 1, "name": "arch-navigation",
            "anatomy": "default", "motion": {"beating": False},
            "dt_ms": self.dt * 1e3, "time_limit_s": 3600, "fine_steps": 4,
            "instruments": [{"name": "wire", "catalogue": ep.instruments[0],
                             "max_nodes": self.wire_nodes, "tip_segment_mm": 2}],
            "input": {"type": "autopilot"},
            "autopilot": [{"action": "navigate", "instrument": "wire",
                           "goal": {"segment": ep.target_segment,
                                    "distance_mm": round(goal * 1e3, 2)},
                           "speed_mm_s": self.velocity_limit[0] * 1e3, "tolerance_mm": 2}],
        }

    def _tree(self, ep):
        return _arch_tree(ep.anatomy, ep.variation)

    def _build(self, ep):
        tree = self._tree(ep)
        sim = _vcsim.Simulator(self._scenario(ep), anatomy=tree)
        # The wire's tip 30 mm out of the introducer sheath.
        steps = max(1, round(0.5 / sim.dt))
        sim.step([[0.055 / 0.5, 0.0]], steps=steps)
        return sim, _vcsim.Autopilot(sim)

    def _isocentre(self, ep):
        return _lines(self._tree(ep))["aortic_arch"]["points"].mean(axis=0)


class CoronaryNavigation(_Navigation):
    """A guiding catheter seated in a coronary ostium and a 0.014" wire inside it, to a target
    in the LAD, LCx or RCA of the beating heart.

    Action: (2, 2), row 0 the guide, row 1 the wire: [translation m/s, rotation rad/s] at
    control_hz. The episode starts with the guide engaged (brought there over a J wire by the
    autopilot, the J wire then removed) and the wire's tip 20 mm inside the guide's (run up while
    the autopilot held the guide seated). Success:
    the wire's tip (carried back to the heart at rest) within target_tolerance of the target.
    Randomised per reset: the patient (right- or left-dominant), coronary and aortic calibre,
    heart rate 55-95 bpm, the wire (floppy or intermediate), the target vessel and depth (40-80
    mm past its ostium) and the C-arm (one of the usual views of that vessel).

    Not every draw can be started: the autopilot seats the JL4 in the left main in a third to a
    half of the LAD/LCx draws (fewer in a wider aorta) and the JR4 in the RCA in more than half
    of the RCA draws
    (docs/measurements.md); reset() draws again, up to max_redraws (20) times, and
    info["redraws"] counts them.
    """

    TARGETS = ("lad", "lcx", "rca")
    GUIDE = {"lad": "catheter-jl4-6f", "lcx": "catheter-jl4-6f", "rca": "catheter-jr4-6f"}
    OSTIUM = {"lad": "left_main", "lcx": "left_main", "rca": "rca"}
    WIRES = ("wire-014-floppy", "wire-014-intermediate")
    # (primary, secondary) deg: LAO cranial and RAO cranial for the LAD, RAO and LAO caudal for
    # the LCx, LAO and RAO for the RCA.
    VIEWS = {"lad": ((40, 30), (-30, 30)), "lcx": ((-20, -25), (40, -25)),
             "rca": ((40, 0), (-30, 0))}
    num_controlled = 2
    _is_coronary = True
    START_GAP = 0.02  # m: the wire's tip this far inside the guide's at the start

    def __init__(self, *, targets=TARGETS, wires=WIRES, dt=5e-4, **kw):
        targets = tuple(targets)
        if not targets or any(t not in self.TARGETS for t in targets):
            raise ValueError(f"targets: expected names among {self.TARGETS}, got {targets}")
        if not wires:
            raise ValueError("wires: expected at least one catalogue entry")
        if not (1e-4 <= float(dt) <= 1e-3):
            raise ValueError(f"dt: expected 1e-4 to 1e-3 s, got {dt}")
        self.targets = targets
        self.wires = tuple(wires)
        self.dt = float(dt)
        kw.setdefault("velocity_limit", (0.03, math.pi))
        super().__init__(**kw)

    def _draw(self, rng):
        r = self.randomize
        anatomy = "left-dominant" if (r and rng.uniform() < 0.3) else "default"
        var = {"coronary_radius_scale": round(_uniform(rng, 0.9, 1.1, r), 3),
               "aorta_radius_scale": round(_uniform(rng, 0.9, 1.1, r), 3)}
        target = self.targets[int(rng.integers(len(self.targets)))] if r else self.targets[0]
        wire = self.wires[int(rng.integers(len(self.wires)))] if r else self.wires[0]
        tree = _patient_tree(anatomy, tuple(sorted(var.items())))
        s0 = _ostium(tree, target)
        dist = round(s0 + _uniform(rng, 0.04, 0.08, r), 4)
        dist = min(dist, tree.segment_length(target) - 5e-3)
        view = self.VIEWS[target][int(rng.integers(2))] if r else self.VIEWS[target][0]
        return Episode(anatomy=anatomy, variation=tuple(sorted(var.items())),
                       instruments=(self.GUIDE[target], wire), target_segment=target,
                       target_distance=dist, primary_deg=float(view[0]),
                       secondary_deg=float(view[1]),
                       heart_rate_bpm=round(_uniform(rng, 55, 95, r), 1))

    def _scenario(self, ep):
        guide, wire = ep.instruments
        ostium = self.OSTIUM[ep.target_segment]
        goal = ep.target_distance - _ostium(self._tree(ep), ep.target_segment)
        return {
            "format": "vcsim-scenario", "version": 1, "name": "coronary-navigation",
            "anatomy": ep.anatomy, "motion": {"beating": True,
                                              "heart_rate_bpm": ep.heart_rate_bpm},
            "dt_ms": self.dt * 1e3, "time_limit_s": 3600,
            "instruments": [
                {"name": "guide", "catalogue": guide, "max_nodes": 256, "tip_segment_mm": 2},
                {"name": "j_wire", "catalogue": "wire-035-j3-hydrophilic", "inside": "guide",
                 "rim": False, "max_nodes": 256, "tip_segment_mm": 2},
                {"name": "wire", "catalogue": wire, "inside": "guide", "rim": False,
                 "max_nodes": 256, "tip_segment_mm": 2}],
            "input": {"type": "autopilot"},
            "autopilot": [
                {"action": "navigate", "instrument": "j_wire",
                 "goal": {"segment": "ascending_aorta", "distance_mm": 10},
                 "follower": "guide", "follow_gap_mm": 40, "speed_mm_s": 150},
                {"action": "withdraw", "instrument": "j_wire", "depth_mm": 0,
                 "speed_mm_s": 300},
                {"action": "navigate", "instrument": "guide",
                 "goal": {"segment": ostium, "distance_mm": 2}, "speed_mm_s": 40,
                 "tolerance_mm": 2, "seat_mm": 3},
                {"action": "remove", "instrument": "j_wire"},
                # The wire run up the guide to START_GAP short of its tip, at half the drive's
                # speed limit (Sheath::max_speed, 0.5 m/s), while the autopilot holds the guide
                # seated: the wire's core entering the JL4's curves pulls its tip back, and a
                # guide merely held at its depth then drops into the sinus (a withdraw relative
                # to the guide moves either way).
                {"action": "withdraw", "instrument": "wire", "relative_to": "guide",
                 "depth_mm": self.START_GAP * 1e3, "speed_mm_s": 250},
                {"action": "navigate", "instrument": "wire",
                 "goal": {"segment": ep.target_segment, "distance_mm": round(goal * 1e3, 2)},
                 "speed_mm_s": 30}],
        }

    def _tree(self, ep):
        return _patient_tree(ep.anatomy, ep.variation)

    def _build(self, ep):
        tree = self._tree(ep)
        sim = _vcsim.Simulator(self._scenario(ep), anatomy=tree)
        pilot = _vcsim.Autopilot(sim)
        # Fewer retries than a run's: a start that does not come quickly is drawn again.
        pilot.max_retries = 6
        if not pilot.run(sim, phases=5, duration=60.0):
            raise StartFailed(f"CoronaryNavigation: the guide could not be seated for {ep} "
                              f"(autopilot: {pilot.status})")
        pilot.max_retries = 16
        guide, wire = sim.depths()
        if (abs(guide - wire - self.START_GAP) > 2e-3
                or sim.tip_location("guide")[0] != self.OSTIUM[ep.target_segment]):
            raise StartFailed(f"CoronaryNavigation: the wire was not brought up the seated guide "
                              f"for {ep} (its tip {(guide - wire) * 1e3:.1f} mm inside the "
                              f"guide's, the guide's tip in "
                              f"{sim.tip_location('guide')[0]!r})")
        return sim, pilot


# ---- anatomies, built once per draw (they are small; the lumen is built with the simulator)
_TREES = collections.OrderedDict()


def _cached(key, make):
    if key in _TREES:
        _TREES.move_to_end(key)
        return _TREES[key]
    t = make()
    _TREES[key] = t
    while len(_TREES) > 64:
        _TREES.popitem(last=False)
    return t


def _arch_tree(anatomy, variation):
    return _cached(("arch", anatomy, variation),
                   lambda: _vcsim.Anatomy.builtin(anatomy).vary(**dict(variation)))


def _patient_tree(anatomy, variation):
    return _cached(("patient", anatomy, variation),
                   lambda: _vcsim.Anatomy.builtin(anatomy).vary(**dict(variation)))


# Centrelines by name per tree (Anatomy.centrelines() converts every segment: 0.1-0.2 ms, more
# than a reset's restore), kept with a reference to their tree so that its id is not reused.
# Only the drawn trees above go in: a Simulator's `anatomy` is a view that keeps the simulator
# (tens of MB) alive, so 64 of them here held 64 dropped starts.
_LINES = collections.OrderedDict()


def _lines(tree):
    key = id(tree)
    if key in _LINES:
        _LINES.move_to_end(key)
        return _LINES[key][1]
    lines = {c["name"]: c for c in tree.centrelines()}
    _LINES[key] = (tree, lines)
    while len(_LINES) > 64:
        _LINES.popitem(last=False)
    return lines


def _ostium(tree, segment):
    return _lines(tree)[segment]["ostium_distance"]
