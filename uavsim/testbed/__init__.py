"""A richer vehicle that makes "measured" sessions for the gap workflow, and only that.

The workflow simulates a lumped loop on a MuJoCo hexarotor built for it
(``uavsim.model``, ``uavsim.sim``) with the effects of ``uavsim.model.effects``.
A real aircraft is none of that, so this package is an aircraft of its own,
never used by the workflow to simulate: a free rigid body in MuJoCo
(``airframe``), six rotors with speed states, thrust ``k_T w^2``, ESC
saturation (1165-1878 us), slew and update rate (``propulsion``), a battery
whose voltage sags under load and over the flight (``battery``), an IMU with
frame vibration at the rotor frequencies, heavy-tailed and quantized noise, a
complementary attitude filter, a camera with frame jitter, dropped frames and
latency, and a camera + IMU Kalman filter for altitude (``sensors``), an
autopilot that mixes with a linear thrust model and holds the other axes
(``flight``), hidden effects written independently of the workflow's,
vocabulary and other shapes (``hidden``), and the session generator with
its truth files (``sessions``). ``vehicle`` draws an aircraft per seed and
gives its lumped equivalent; ``equivalence`` measures how close it is;
``score`` runs the gap workflow on a set of its sessions and scores the
answers against the truth files (``uavsim testbed score``).

    from uavsim.testbed import testbed_session, write_testbed
    session, truth = testbed_session(7)              # no [model]: the user's case
    write_testbed(session, truth, "out/tb/tb_00007")  # + out/tb/tb_00007.truth.json

    uavsim testbed sessions --seeds 0:12 --out out/testbed
"""

from uavsim.testbed.hidden import OUTSIDE, VOCABULARY, HiddenEffect, Scales, draw_effect
from uavsim.testbed.sessions import (
    DEV_SEEDS,
    HELDOUT_SEEDS,
    KINDS,
    RECIPE,
    TestbedTruth,
    plan_session,
    read_truth,
    testbed_session,
    write_testbed,
)
from uavsim.testbed.vehicle import TestbedVehicle, draw_vehicle, lumped_equivalent

__all__ = [
    "DEV_SEEDS",
    "HELDOUT_SEEDS",
    "KINDS",
    "OUTSIDE",
    "RECIPE",
    "VOCABULARY",
    "HiddenEffect",
    "Scales",
    "TestbedTruth",
    "TestbedVehicle",
    "draw_effect",
    "draw_vehicle",
    "lumped_equivalent",
    "plan_session",
    "read_truth",
    "testbed_session",
    "write_testbed",
]
