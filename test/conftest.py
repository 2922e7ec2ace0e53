"""Shared fixtures for the dynamics tests: a seeded family of random kinematic trees."""
from __future__ import annotations

import dataclasses
import os

import numpy as np
import pytest

from robodyn_ros.model import build_model, random_tree

#: number of random trees in the ``trees`` fixture (tests assert that they saw all of them)
N_TREES = 24


def _with_fixed(model, fixed_links, name):
    """Rebuild ``model`` from its LinkSpecs with the joints of ``fixed_links`` made FIXED."""
    specs = [dataclasses.replace(s, joint_type='fixed') if s.name in fixed_links else s for s in model.specs]
    return build_model(specs, gravity=model.gravity, name=name)


def make_trees():
    """``N_TREES`` seeded models ``(label, model)``: chains and branched trees with 1..12 bodies,
    revolute and prismatic joints, a few gravity directions, and three trees with FIXED joints in
    the middle of the tree (built from LinkSpecs)."""
    out = []
    fractions = (0.0, 0.3, 0.6, 1.0)
    for k in range(21):
        rng = np.random.default_rng(1000 + k)
        nb = 1 + k % 12
        chain = k % 3 == 0
        frac = fractions[k % 4]
        g = (0.0, 0.0, -9.81) if k % 5 else tuple(9.81 * rng.normal(size=3) / np.sqrt(3.0))
        m = random_tree(nb, rng, prismatic_fraction=frac, chain=chain, gravity=g)
        out.append((f'seed{1000 + k}-nb{nb}-{"chain" if chain else "tree"}-p{frac}', m))
    # FIXED joints mid-tree: a chain with a welded middle link, a branched tree with two welds
    # (one of them a leaf), and a chain where two consecutive joints are welded
    m = random_tree(7, np.random.default_rng(2001), prismatic_fraction=0.3, chain=True)
    out.append(('fixed-mid-chain7', _with_fixed(m, {'l3'}, 'fixed_mid_chain')))
    m = random_tree(10, np.random.default_rng(2002), prismatic_fraction=0.3, chain=False)
    leaf = [n for i, n in enumerate(m.link_names) if i not in set(m.parent.tolist())][-1]
    out.append(('fixed-tree10', _with_fixed(m, {'l2', leaf}, 'fixed_tree')))
    m = random_tree(8, np.random.default_rng(2003), prismatic_fraction=0.5, chain=True)
    out.append(('fixed-double-chain8', _with_fixed(m, {'l4', 'l5'}, 'fixed_double')))
    assert len(out) == N_TREES
    return out


@pytest.fixture(scope='session')
def trees():
    """The seeded random trees of :func:`make_trees`."""
    return make_trees()


def random_state(model, rng, scale=1.0):
    """A random ``(q, v, a)`` for a model with 1-DOF joints only (q = v coordinates)."""
    assert model.nq == model.nv
    q = rng.uniform(-np.pi, np.pi, size=model.nq) * scale
    v = rng.normal(size=model.nv) * scale
    a = rng.normal(size=model.nv) * scale
    return q, v, a


@pytest.fixture(scope='session')
def state_of():
    """The :func:`random_state` helper (fixtures are the way test modules share code here)."""
    return random_state


@pytest.fixture(autouse=True)
def _no_process_outlives_its_test():
    """A node or controller process a test started and left running (its test failed before the
    cleanup) is killed when the test ends, so that it cannot publish into a later test's ROS domain.
    Processes of module-scoped fixtures are set up before this fixture and stay for their module;
    the session's end kills those (:func:`pytest_sessionfinish`)."""
    import sys
    helpers = sys.modules.get('ros_helpers')
    since = len(helpers.Proc.started) if helpers else 0
    yield
    helpers = sys.modules.get('ros_helpers')
    if helpers is not None:
        helpers.kill_left_over(since)


def pytest_configure(config):
    """Take Ctrl-C (SIGINT) as a terminal's foreground process does, also when started ignoring it.

    A command started in the background of a non-interactive shell (``pytest ... &`` in a script)
    inherits SIGINT ignored, and so does every process it starts: Python then installs no
    KeyboardInterrupt handler. The tests that Ctrl-C a child (the sweep's, the live run's) stand for
    a user at a terminal; with SIGINT ignored their child would go on and the test would wait for its
    exit until its timeout (the loaded ``-m processes`` step, run that way, timed out in the sweep's
    Ctrl-C test). A handler here becomes SIG_DFL in each child at exec, where Python installs its own."""
    import signal
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


def pytest_sessionfinish(session, exitstatus):
    """Kill any helper process still running at the end of the session."""
    import sys
    helpers = sys.modules.get('ros_helpers')
    if helpers is not None:
        helpers.kill_left_over(0)


#: the test files that keep a worker longest (half a minute or more each, mostly in child processes),
#: collected first: pytest-xdist hands out whole files (``--dist loadfile``) in collection order, so
#: these start at once and the short files fill in around them, and the two workers end together
#: (in alphabetical order test_sweep.py and test_urdf_fuzz.py came last, one worker running them alone).
#: On an empty cache the files that compile models' generated code come first (minutes each: on a fresh clone
#: test_generated.py's ground recordings took 2 min, test_armature.py's generated trees 2 min)
LONG_FILES = ('test_generated.py', 'test_kernels.py', 'test_armature.py', 'test_cold_start.py', 'test_sweep.py',
              'test_startup.py', 'test_live.py', 'test_determinism.py', 'test_bench_peers.py', 'test_urdf_fuzz.py',
              'test_node_urdf.py', 'test_step_budget.py')


def pytest_collection_modifyitems(config, items):
    if not os.environ.get("PYTEST_XDIST_WORKER"):   # only to spread xdist's workers; a serial run keeps
        return                                      # the alphabetical order
    rank = {name: i for i, name in enumerate(LONG_FILES)}
    items.sort(key=lambda item: rank.get(item.path.name, len(LONG_FILES)))   # stable: the rest keep their order
