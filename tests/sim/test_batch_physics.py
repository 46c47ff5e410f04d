"""The simulator's physics on ``mujoco.batch``: per-member models, step noise, the C current
limit, warnings, against dedicated ``MjData`` stepping."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from testbed.sim import build_simulator


def _drive(sim, steps: int = 120, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    high = np.asarray(sim.rig.action_high) * 1.2
    out = []
    for _ in range(steps):
        sim.step(rng.uniform(-1, 1, (sim.num, sim.rig.n_actions)) * high)
        out.append(np.concatenate([sim.info["state"].ravel(), sim.obs.ravel()]))
    return np.array(out)


def test_current_limit_in_c_equals_the_python_substep_hook():
    runs = []
    for native in (True, False):
        sim = build_simulator("helicopter", 3, num_threads=2, profile="hardware")
        if not native:
            sim.physics._native = None  # the rig's substep_ctrl, vectorized, in Python
        sim.reset(None, [0, 1, 2])
        runs.append(_drive(sim))
        sim.close()
    np.testing.assert_array_equal(runs[0], runs[1])


def test_member_models_are_the_rigs_model_with_their_parameters_and_step_noise():
    sim = build_simulator("vehicle-roll", 3, num_threads=2)
    params = [{"roll_stiffness": 1.1}, None, {"roll_damping": 0.9, "sprung_mass_kg": 1.05}]
    sim.reset(None, [0, 1, 2], options={"params": params})
    for i, p in enumerate(params):
        expected = sim.rig.model_with(sim.nominal_params.scaled(p or {}))
        got = sim.physics.models[i]
        for name in ("body_mass", "body_inertia", "jnt_stiffness", "dof_damping",
                     "body_subtreemass", "dof_invweight0"):
            np.testing.assert_array_equal(getattr(got, name), getattr(expected, name), name)
    sim.step(np.zeros((3, 1)))
    xi = sim.info["step_noise"][:, 0]
    c = sim.physics.constants
    damping = [sim.physics.models[i].dof_damping[sim.rig.dof_adr[0]] for i in range(3)]
    np.testing.assert_array_equal(damping, c[:, 1] + c[:, 2] * xi)
    sim.close()


def test_a_member_equals_a_dedicated_mjdata():
    """Member 1 of a batch, stepped with its held inputs, equals mj_step on its own data."""
    sim = build_simulator("helicopter", 3, num_threads=2, ambient_noise=0.0)
    sim.reset(None, [0, 1, 2], options={"params": [None, {"mass_kg": 1.1}, None]})
    model = sim.physics.models[1]
    data = sim.physics.batch.get_data(1)
    u = np.tile([[2.0, -1.0]], (3, 1))
    for _ in range(20):
        sim.step(u)
        data.ctrl[:] = u[1]
        mujoco.mj_step(model, data, nstep=sim.frame_skip)
        np.testing.assert_array_equal(
            sim.info["state"][1], np.concatenate([data.qpos, data.qvel])[sim.rig.state_gather])
    sim.close()


def test_the_c_callback_stays_installed_and_is_used():
    from testbed.sim import native

    sim = build_simulator("helicopter", 2, num_threads=1, profile="hardware")
    if sim.physics._native is None:
        import pytest

        pytest.skip("no C compiler here: the Python hook runs")
    assert native.installed()
    sim.close()


@pytest.mark.parametrize("num", [1, 3])
def test_simulator_pickles_mid_episode_and_continues_identically(num):
    import pickle

    for rig, profile in (("vehicle-roll", "paper"), ("helicopter", "hardware")):
        sim = build_simulator(rig, num, num_threads=2, profile=profile)
        sim.reset(None, list(range(num)),
                  options={"params": [None, {"mass_kg": 1.1}, None][:num]}
                  if rig == "helicopter" else None)
        _drive(sim, 20)
        copy = pickle.loads(pickle.dumps(sim))
        np.testing.assert_array_equal(_drive(sim, 30, seed=5), _drive(copy, 30, seed=5))
        sim.close()
        copy.close()


@pytest.mark.parametrize("rig, options", [
    ("helicopter", {"profile": "paper"}),
    ("helicopter", {"profile": "hardware"}),
    ("helicopter", {"disturbance": "basin-helicopter", "process_noise": 1.0,
                    "sensors": "paper", "sensor_kwargs": {"disturbance_channel": True}}),
    ("helicopter", {"setpoints": [[0.0, 0.1, 0.2], [0.05, -0.1, 0.4], [0.12, 0.0, 0.0]]}),
    ("vehicle-roll", {"profile": "paper"}),
    ("vehicle-roll", {"profile": "hardware", "manoeuvre": "double-lane-change"}),
])
def test_one_member_step_equals_a_member_of_a_batch(rig, options):
    """A one-member simulator steps on Python floats (``Simulator._step_single``, the
    fused sensors' one-row path): bitwise the observation, reward, termination and every
    info entry of the same member in a batch, with clipped actions, the ambient
    disturbance, setpoint switches, a manoeuvre or a disturbance signal."""
    one = build_simulator(rig, 1, num_threads=1, **options)
    many = build_simulator(rig, 3, num_threads=2, **options)
    assert one._single and not many._single
    one.reset(None, [7], None)
    many.reset(None, [5, 7, 9], None)
    rng = np.random.default_rng(1)
    high = np.asarray(one.rig.action_high)
    for k in range(40):
        u = rng.uniform(-1.3, 1.3, (3, one.rig.n_actions)) * high
        if k % 5 == 0:
            u[1, -1] = -0.0  # (a signed zero: applied as +0.0, as clipped + 0)
        one.step(u[1:2])
        many.step(u)
        assert one.obs.tobytes() == many.obs[1:2].tobytes()
        assert one.reward.tobytes() == many.reward[1:2].tobytes()
        assert one.terminated.tobytes() == many.terminated[1:2].tobytes()
        assert one.steps.tobytes() == many.steps[1:2].tobytes()
        for key, value in one.info.items():
            assert value.tobytes() == many.info[key][1:2].tobytes(), key
        got, expected = one.member_info(0), many.member_info(1)
        assert list(got) == list(expected)
        for key, value in got.items():
            assert np.asarray(value).tobytes() == np.asarray(expected[key]).tobytes(), key
    one.close()
    many.close()


def test_plain_step_with_and_without_the_batch_private_c_call():
    """``Physics.step_plain`` calls the batch's C step (``Batch._b.step``) where MuJoCo has
    it, else the public ``Batch.step``: the same states, and the same warning handling
    (``_mark_unstable``, shared with the general step)."""
    from testbed.sim.simulator import SimulationDiverged

    sims = [build_simulator("helicopter", 1, num_threads=1, ambient_noise=0.0)
            for _ in range(2)]
    sims[1].physics._c_step = None  # a MuJoCo without the private call
    rng = np.random.default_rng(3)
    us = rng.uniform(-1.2, 1.2, (25, 1, 2)) * np.asarray(sims[0].rig.action_high)
    states = []
    for sim in sims:
        sim.reset(None, [0])

        def general(*args, **kwargs):
            raise AssertionError("the one-member step took the general physics step")

        sim.physics.step = general  # (the plain path must be the one taken)
        for u in us:
            sim.step(u)
        states.append(sim.info["state"].copy())
        sim.physics.state[0, sim.physics._gather[2]] = 1e30  # a huge pitch rate: bad qacc
        with pytest.raises(SimulationDiverged, match="mujoco warning|MuJoCo"):
            sim.step(np.zeros((1, 2)))
        assert sim.physics.unstable[0] and not sim.physics._bad.any()
        sim.reset(None, [0])
        sim.step(np.zeros((1, 2)))
        assert not sim.physics.unstable[0]
        sim.close()
    assert states[0].tobytes() == states[1].tobytes()


def test_general_step_with_and_without_the_batch_private_c_call():
    """The general step of the whole batch (the vehicle's step noise takes it) calls the same
    C step as :meth:`Physics.step_plain`: the same states bitwise as the public
    ``Batch.step``, one member and several."""
    for num in (1, 3):
        sims = [build_simulator("vehicle-roll", num, num_threads=1) for _ in range(2)]
        sims[1].physics._c_step = None
        rng = np.random.default_rng(4)
        us = rng.uniform(-4.0, 4.0, (25, num, 1))
        states = []
        for sim in sims:
            sim.reset(None, list(range(5, 5 + num)))
            general, calls = sim.physics.step, []

            def counted(*args, general=general, calls=calls, **kwargs):
                calls.append(1)
                return general(*args, **kwargs)

            sim.physics.step = counted
            for u in us:
                sim.step(u)
            assert len(calls) == len(us)  # the general path (the rig's step noise)
            states.append(sim.info["state"].copy())
            sim.close()
        assert states[0].tobytes() == states[1].tobytes()


def test_whole_batch_step_equals_the_members_step_bitwise():
    """The whole batch's step (its slice, the reused force rows, the one-time profile and
    reference) gives, bitwise, what stepping every member by index gives (the general path)."""
    info_keys = ("state", "t", "setpoint", "action_applied", "action_clipped", "manoeuvre",
                 "process_accel", "step_noise")
    runs = []
    for members in (None, np.arange(4)):
        sim = build_simulator("vehicle-roll", 4, num_threads=1, manoeuvre="double-lane-change")
        assert sim.inputs.active and not sim.schedules.none  # the paths under test
        sim.reset(None, [3, 1, 4, 1])
        rng = np.random.default_rng(5)
        high = np.asarray(sim.rig.action_high) * 1.2
        out = []
        for _ in range(150):
            sim.step(rng.uniform(-1, 1, (4, 1)) * high, members)
            out.append(b"".join(np.ascontiguousarray(a).tobytes() for a in
                                [sim.obs, sim.reward, sim.terminated]
                                + [sim.info[key] for key in info_keys]))
        runs.append(out)
    assert runs[0] == runs[1]


@pytest.mark.parametrize("rig", ["vehicle-roll", "helicopter"])
def test_whole_batch_mass_store_equals_the_indexed_one(rig):
    """The whole batch's dense mass write (slices, one write for a diagonal M) gives, bitwise,
    the per-index write."""
    from testbed.sim.simulator import _ALL

    sim = build_simulator(rig, 3, num_threads=1)
    sim.reset(None, [0, 1, 2])
    sim.step(np.zeros((3, sim.rig.n_actions)))
    physics = sim.physics
    physics._mass_bound = physics.batch.bind("M")
    physics._store_mass(_ALL)
    whole = physics.mass.copy()
    physics.mass[...] = 0.0  # (as made: positions outside M's pattern stay zero)
    physics._store_mass(np.arange(3))
    assert whole.tobytes() == physics.mass.tobytes()
    assert np.all(np.diagonal(whole, axis1=1, axis2=2) > 0)  # the masses were written


def test_a_copied_physics_stores_the_mass_in_its_own_matrix():
    """The dense mass is written through a kept flat view of ``mass``: a deep copy (and an
    unpickled physics) writes its own ``mass``, not the original's, bitwise as the
    original."""
    import copy
    import pickle

    sim = build_simulator("vehicle-roll", 3, num_threads=1)
    sim.reset(None, [0, 1, 2])
    sim.step(np.full((3, 1), 2.0))
    twins = [copy.deepcopy(sim), pickle.loads(pickle.dumps(sim))]
    for s in [sim, *twins]:
        for k in range(5):
            s.step(np.full((3, 1), -1.0 + k))
    for twin in twins:
        assert twin.physics.mass.tobytes() == sim.physics.mass.tobytes()
        assert twin.physics._mass_flat.base is twin.physics.mass
    assert sim.physics._mass_flat.base is sim.physics.mass
