"""The compiled module: state as arrays, stepping, snapshot and restore, anatomy, imaging and
clear errors."""
import threading

import numpy as np
import pytest

import vcsim
from conftest import arch_scenario


def push(sim, speed=0.05, seconds=0.5, rot=0.0):
    sim.step([[speed, rot]], steps=round(seconds / sim.dt))


def test_state_arrays_follow_the_push(arch_sim):
    sim = arch_sim
    assert sim.num_instruments == 1 and sim.instrument_names == ["wire"]
    assert sim.depths()[0] == 0.0
    push(sim, 0.05, 0.5)
    # Velocity mode: 50 mm/s for 0.5 s inserts 25 mm (the drive follows its command).
    assert sim.depths()[0] == pytest.approx(0.025, abs=1e-4)
    assert sim.time == pytest.approx(0.5)
    tips = sim.tips()
    assert tips.shape == (1, 3) and np.all(np.isfinite(tips))
    x = sim.positions("wire")
    assert x.ndim == 2 and x.shape[1] == 3 and len(x) >= 2
    assert np.allclose(x[-1], tips[0])
    # The inserted part is a subset of the whole rod.
    assert len(sim.positions(0, inserted_only=False)) >= len(x)
    f = sim.hand_forces()
    assert f.shape == (1, 2) and np.all(np.isfinite(f))
    c = sim.contacts(0)
    assert set(c) == {"node", "normal", "depth", "force"}
    assert c["normal"].shape == (len(c["node"]), 3)
    seg, dist, outside = sim.tip_location(0)
    assert seg == "thoracic_aorta" and dist > 0 and outside < 0


def test_position_mode_reaches_the_commanded_depth(arch_sim):
    arch_sim.step([[0.03, 0.5]], steps=800, mode="position")
    assert arch_sim.depths()[0] == pytest.approx(0.03, abs=5e-4)
    assert arch_sim.rolls()[0] == pytest.approx(0.5, abs=1e-2)


def test_snapshot_and_restore_replay_bit_for_bit(arch_sim):
    sim = arch_sim
    push(sim, 0.05, 0.3)
    snap = sim.snapshot()
    assert snap.time == pytest.approx(sim.time) and snap.hash == sim.state_hash
    push(sim, 0.04, 0.4, rot=1.0)
    after = sim.state_hash
    tips = sim.tips()
    sim.restore(snap)
    assert sim.state_hash == snap.hash and sim.time == pytest.approx(0.3)
    push(sim, 0.04, 0.4, rot=1.0)
    assert sim.state_hash == after
    assert np.array_equal(sim.tips(), tips)
    sim.restore(snap)
    push(sim, 0.04, 0.4, rot=-1.0)
    assert sim.state_hash != after


def test_a_snapshot_of_another_scene_is_refused(arch_tree, arch_sim):
    sc = arch_scenario()
    sc["instruments"] = [{"name": "catheter", "catalogue": "catheter-jl4-6f", "max_nodes": 64},
                         {"name": "wire", "catalogue": "wire-035-angled-hydrophilic",
                          "inside": "catheter", "max_nodes": 64}]
    other = vcsim.Simulator(sc, anatomy=arch_tree)
    with pytest.raises(vcsim.InputError, match="instrument count"):
        arch_sim.restore(other.snapshot())
    assert arch_sim.time == 0.0


def test_bad_actions_raise_naming_the_argument(arch_sim):
    with pytest.raises(ValueError, match=r"action: expected shape \(1, 2\).*got \(3,\)"):
        arch_sim.step([1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="action: expected finite values.*instrument 'wire'"):
        arch_sim.step([[float("nan"), 0.0]])
    with pytest.raises(ValueError, match="mode: expected 'velocity' or 'position'"):
        arch_sim.step([[0.0, 0.0]], mode="force")
    with pytest.raises(ValueError, match="steps: expected at least 1"):
        arch_sim.step([[0.0, 0.0]], steps=0)
    with pytest.raises(ValueError, match="no instrument named 'catheter'.*wire"):
        arch_sim.positions("catheter")
    with pytest.raises(IndexError, match="instrument: expected an index in"):
        arch_sim.contacts(3)
    # Nothing changed.
    assert arch_sim.time == 0.0


def test_bad_scenarios_and_anatomies_raise_input_errors(arch_tree):
    sc = arch_scenario()
    sc["instruments"][0]["catalogue"] = "wire-that-does-not-exist"
    with pytest.raises(vcsim.InputError, match=r"instruments\[0\]\.catalogue"):
        vcsim.Simulator(sc, anatomy=arch_tree)
    assert issubclass(vcsim.InputError, ValueError)
    with pytest.raises(vcsim.InputError, match="name: expected default.*arch.*no-such-patient"):
        vcsim.Anatomy.builtin("no-such-patient")
    with pytest.raises(vcsim.InputError, match="tortuosity"):
        arch_tree.vary(tortuosity=0.5)
    with pytest.raises(vcsim.InputError, match="arch_elongation"):
        vcsim.Anatomy.builtin("default").vary(arch_elongation=0.01)
    with pytest.raises(TypeError, match="scenario"):
        vcsim.Simulator(42)


def test_anatomy_arrays_and_variations(arch_tree):
    cl = {c["name"]: c for c in arch_tree.centrelines()}
    assert {"aortic_arch", "brachiocephalic", "left_common_carotid", "left_subclavian",
            "thoracic_aorta"} <= set(cl)
    assert not arch_tree.has_heart
    assert arch_tree.access[0] == "thoracic_aorta"
    arch = cl["aortic_arch"]
    assert arch["points"].shape == (len(arch["radii"]), 3)
    wide = arch_tree.vary(aorta_radius_scale=1.2, artery_radius_scale=0.9)
    wcl = {c["name"]: c for c in wide.centrelines()}
    assert np.allclose(wcl["aortic_arch"]["radii"], 1.2 * arch["radii"])
    assert np.allclose(wcl["left_subclavian"]["radii"], 0.9 * cl["left_subclavian"]["radii"])
    assert np.array_equal(wcl["aortic_arch"]["points"], arch["points"])
    # Elongation raises the arch top by its amount; the valve end stays.
    up = {c["name"]: c for c in arch_tree.vary(arch_elongation=0.02).centrelines()}
    assert up["aortic_arch"]["points"][:, 2].max() == pytest.approx(
        arch["points"][:, 2].max() + 0.02, abs=1e-3)
    assert np.allclose(up["aortic_root"]["points"][0], cl["aortic_root"]["points"][0])
    # Tortuosity: a smooth field of the given rms size, the same for the same seed; branches
    # stay attached to their parent.
    t1 = arch_tree.vary(tortuosity=0.003, seed=7)
    t2 = arch_tree.vary(tortuosity=0.003, seed=7)
    t3 = arch_tree.vary(tortuosity=0.003, seed=8)
    p1 = np.concatenate([c["points"] for c in t1.centrelines()])
    p0 = np.concatenate([c["points"] for c in arch_tree.centrelines()])
    assert np.array_equal(p1, np.concatenate([c["points"] for c in t2.centrelines()]))
    assert not np.array_equal(p1, np.concatenate([c["points"] for c in t3.centrelines()]))
    d = np.linalg.norm(p1 - p0, axis=1)
    assert 0.001 < np.sqrt(np.mean(d**2)) < 0.009
    t1c = {c["name"]: c for c in t1.centrelines()}
    bc = t1c["brachiocephalic"]["points"][0]
    seg, _, outside = t1.locate(bc)
    assert outside < 0  # the branch's first point is inside the (moved) arch's lumen


def test_path_length_along_the_centrelines(arch_tree):
    L = arch_tree.segment_length("aortic_arch")
    assert arch_tree.path_length("aortic_arch", 0.0, "aortic_arch", L) == pytest.approx(L, rel=0.01)
    with pytest.raises(ValueError, match="no segment named 'lad'"):
        arch_tree.path_length("lad", 0, "aortic_arch", 0)


def test_lumen_mesh_is_closed_around_the_centrelines(arch_sim, arch_tree):
    v, f = arch_sim.lumen_mesh()
    assert v.shape[1] == 3 and f.shape[1] == 3 and f.max() < len(v) and len(f) > 1000
    p = arch_tree.point_at("aortic_arch", 0.03)
    r = {c["name"]: c for c in arch_tree.centrelines()}["aortic_arch"]["radii"].min()
    # Every vertex near this centreline point lies about a radius away (within 30 %).
    near = np.linalg.norm(v - p, axis=1)
    assert near.min() > 0.7 * r


def test_carm_projection_and_fluoroscopy(arch_sim, arch_tree):
    iso = arch_tree.point_at("aortic_arch", 0.04)
    carm = vcsim.CArm(primary_deg=30, secondary_deg=0, fov=0.2, isocentre=iso)
    assert np.allclose(carm.project(iso[None, :]), 0.0, atol=1e-12)
    with pytest.raises(vcsim.InputError, match="primary_deg"):
        vcsim.CArm(primary_deg=200)
    with pytest.raises(ValueError, match=r"points: expected shape \(k, 3\)"):
        carm.project(np.zeros(3))
    push(arch_sim, 0.1, 1.0)
    f = vcsim.Fluoroscopy(arch_sim, size=64)
    img = f.image(arch_sim, carm, dose=0, seed=1)
    assert img.shape == (64, 64) and img.dtype == np.uint8
    # The wire (radiopaque, thin) darkens the pixels it projects on.
    tip = arch_sim.tips()[0]
    uv = carm.project(tip[None, :])[0]
    col = int(round((uv[0] / 0.2 + 0.5) * 63))
    row = int(round((0.5 - uv[1] / 0.2) * 63))
    assert 0 <= row < 64 and 0 <= col < 64
    patch = img[max(row - 2, 0):row + 3, max(col - 2, 0):col + 3].astype(float)
    assert patch.min() < np.median(img) - 10


def test_stepping_releases_the_gil(arch_tree):
    """Two simulators stepped in two threads give what each gives alone."""
    sims = [vcsim.Simulator(arch_scenario(), anatomy=arch_tree) for _ in range(2)]
    alone = vcsim.Simulator(arch_scenario(), anatomy=arch_tree)
    push(alone, 0.06, 1.0, rot=0.5)
    threads = [threading.Thread(target=push, args=(s, 0.06, 1.0, 0.5)) for s in sims]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sims[0].state_hash == sims[1].state_hash == alone.state_hash


def test_step_many_and_one_thread_give_the_same_states(arch_tree):
    """step_many steps simulators together as each steps alone, and a simulator kept to one
    thread (threads=1) follows the same trajectory bit for bit as one using every core."""
    alone = vcsim.Simulator(arch_scenario(), anatomy=arch_tree)
    assert alone.threads == 0
    push(alone, 0.06, 1.0, rot=0.5)
    one = vcsim.Simulator(arch_scenario(), anatomy=arch_tree)
    one.threads = 1
    assert one.threads == 1
    push(one, 0.06, 1.0, rot=0.5)
    assert one.state_hash == alone.state_hash
    sims = [vcsim.Simulator(arch_scenario(), anatomy=arch_tree) for _ in range(2)]
    sims[1].threads = 1
    n = round(1.0 / sims[0].dt)
    vcsim.step_many(sims, [[[0.06, 0.5]], [[0.06, 0.5]]], [n // 2, n // 2])
    vcsim.step_many(sims, [[[0.06, 0.5]], [[0.06, 0.5]]], [n - n // 2, n - n // 2])
    assert sims[0].state_hash == sims[1].state_hash == alone.state_hash


def test_step_many_checks_everything_before_stepping(arch_tree):
    sims = [vcsim.Simulator(arch_scenario(), anatomy=arch_tree) for _ in range(2)]
    h = [s.state_hash for s in sims]
    with pytest.raises(ValueError, match="as many actions"):
        vcsim.step_many(sims, [[[0.01, 0.0]]], [1, 1])
    with pytest.raises(ValueError, match="appears twice"):
        vcsim.step_many([sims[0], sims[0]], [[[0.01, 0.0]]] * 2, [1, 1])
    # The second action is bad: neither simulator moves.
    with pytest.raises(ValueError, match="finite"):
        vcsim.step_many(sims, [[[0.01, 0.0]], [[float("nan"), 0.0]]], [1, 1])
    with pytest.raises(ValueError, match="steps"):
        vcsim.step_many(sims, [[[0.01, 0.0]]] * 2, [1, 0])
    with pytest.raises(ValueError, match="threads"):
        sims[0].threads = -1
    assert [s.state_hash for s in sims] == h


def test_the_stepper_steps_as_each_simulator_alone_and_returns_each_slot_once(arch_tree):
    alone = vcsim.Simulator(arch_scenario(), anatomy=arch_tree)
    push(alone, 0.06, 1.0, rot=0.5)
    sims = [vcsim.Simulator(arch_scenario(), anatomy=arch_tree) for _ in range(2)]
    sims[0].threads = 1
    stepper = vcsim.Stepper(2)
    assert len(stepper) == 2 and stepper.running == 0
    n = round(1.0 / sims[0].dt)
    for steps in (n // 2, n - n // 2):
        for i, s in enumerate(sims):
            stepper.start(i, s, [[0.06, 0.5]], steps)
        assert stepper.running == 2
        assert sorted(stepper.wait() for _ in range(2)) == [0, 1]
    assert sims[0].state_hash == sims[1].state_hash == alone.state_hash


def test_the_stepper_refuses_what_would_race(arch_tree):
    sims = [vcsim.Simulator(arch_scenario(), anatomy=arch_tree) for _ in range(2)]
    h = sims[1].state_hash
    stepper = vcsim.Stepper(2)
    with pytest.raises(ValueError, match="no slot is stepping"):
        stepper.wait()
    with pytest.raises(IndexError, match="slot"):
        stepper.start(2, sims[0], [[0.01, 0.0]], 1)
    with pytest.raises(ValueError, match="finite"):
        stepper.start(1, sims[1], [[float("nan"), 0.0]], 1)
    assert stepper.running == 0
    stepper.start(0, sims[0], [[0.01, 0.0]], 200)
    with pytest.raises(ValueError, match="still stepping"):
        stepper.start(0, sims[1], [[0.01, 0.0]], 1)
    with pytest.raises(ValueError, match="already stepping"):
        stepper.start(1, sims[0], [[0.01, 0.0]], 1)
    assert stepper.wait() == 0 and stepper.running == 0
    assert sims[1].state_hash == h
    del stepper  # with a step under way: it finishes, then the threads end
    stepper = vcsim.Stepper(1)
    stepper.start(0, sims[1], [[0.01, 0.0]], 500)
    del stepper
    assert sims[1].state_hash != h
