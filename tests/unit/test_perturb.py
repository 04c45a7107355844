"""ParticleSystem.perturb_velocities: the seeded velocity perturbation of the replicas of a
branch (checkpoint.perturb_velocity): its RMS, zero net momentum, held feeds and held clump
components untouched, clump members moving with their body, independence of storage order."""

import numpy as np
import pytest

from cfddem.config import load_case
from cfddem.errors import CaseError
from cfddem.particles import LinearContact, ParticleSystem
from cfddem.particles.clumps import pellet

PP = LinearContact(k_n=2000.0, e_n=0.5, e_t=0.5, mu=0.4)


def _system():
    s = ParticleSystem(pp=PP, walls=[], dt=1e-5)
    rng = np.random.default_rng(3)
    pos = np.c_[np.arange(30) * 0.01, np.zeros(30), np.zeros(30)]
    s.add_particles(pos, rng.normal(size=(30, 3)), np.full(30, 0.002), 2500.0)
    s.add_particles(pos[:5] + [0, 0.05, 0], np.tile([0.0, 0.0, 1.5], (5, 1)), np.full(5, 0.002), 2500.0,
                    held=True)
    s.add_clumps(pellet(2, 0.004, 2500.0), pos[:4] + [0, 0.1, 0], vel=np.tile([0.2, 0.0, 0.0], (4, 1)))
    s.clumps.vfix[3] = [0.0, 0.0, 1.0]  # a feed pellet: its streamwise velocity is held
    s.clumps.vset[3] = [0.0, 0.0, 0.2]
    return s


def _units(s):
    """(velocities of the free spheres by id, of the clumps by body id, of the members, held)."""
    ids, body = s.ids, s.body
    free = (body < 0) & ~s.held
    o = np.argsort(ids[free])
    return s.vel[free][o].copy(), s.clumps.vel.copy(), s.vel[body >= 0].copy(), s.vel[s.held].copy()


def test_perturbation_rms_momentum_and_held_particles():
    s = _system()
    f0, b0, m0, h0 = _units(s)
    k = s.perturb_velocities(1e-6, seed=7)
    assert k == 30 + 3  # 30 free spheres, 3 of the 4 clumps (one has a held component)
    f1, b1, m1, h1 = _units(s)
    dv = np.r_[f1 - f0, b1[:3] - b0[:3]]
    assert np.sqrt(np.mean(np.sum(dv**2, axis=1))) == pytest.approx(1e-6, rel=1e-9)
    mass = np.r_[s.mass[(s.body < 0) & ~s.held], s.clumps.mass[:3]]
    assert np.linalg.norm((mass[:, None] * dv).sum(axis=0)) < 1e-8 * mass.sum() * 1e-6  # round-off of v - v0 (|v| ~ 1 m/s)
    assert np.array_equal(h1, h0) and np.array_equal(b1[3], b0[3])
    # every member moves with its body: the members' change is their body's change
    body = s.body[s.body >= 0]
    assert np.allclose(m1 - m0, (b1 - b0)[body], rtol=0, atol=1e-18)
    assert np.all(np.abs(dv) > 0)


def test_same_seed_same_draws_whatever_the_storage_order():
    a, b = _system(), _system()
    # the same particles stored in another order (as after a neighbour-list rebuild)
    order = np.r_[np.arange(29, -1, -1), np.arange(30, b.n)]
    for name in ("pos", "vel", "omega", "radius", "mass", "inertia", "ids", "body", "held"):
        arr = getattr(b, "_" + name)
        arr[: b.n] = arr[: b.n][order].copy()
    a.perturb_velocities(2e-6, seed=1)
    b.perturb_velocities(2e-6, seed=1)
    ia, ib = np.argsort(a.ids), np.argsort(b.ids)
    assert np.array_equal(a.vel[ia], b.vel[ib])
    c = _system()
    c.perturb_velocities(2e-6, seed=2)
    assert not np.allclose(c.vel[np.argsort(c.ids)], a.vel[ia], rtol=0, atol=1e-9)


def test_perturbation_keys_are_checked(tmp_path):
    with pytest.raises(CaseError, match=r"^checkpoint.perturb_velocity: .*start_from"):
        load_case("cases/box_small", overrides={"checkpoint.perturb_velocity": 1e-6})
    with pytest.raises(CaseError, match=r"^checkpoint.perturb_velocity: -1e-06 is out of range"):
        load_case("cases/box_small", overrides={"checkpoint.perturb_velocity": -1e-6})
    with pytest.raises(CaseError, match=r"^checkpoint.perturb_seed: expected an integer"):
        load_case("cases/box_small", overrides={"checkpoint.perturb_seed": 1.5})
    with pytest.raises(CaseError, match=r"^checkpoint.perturb_seed: -1 is out of range"):
        load_case("cases/box_small", overrides={"checkpoint.perturb_seed": -1})
