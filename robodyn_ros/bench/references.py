"""The simulators measured beside ours in ``robodyn bench speed``: Pinocchio (the exported URDF,
or the tree built joint by joint when it has spherical joints) stepped by a Python RK4 loop over
``pin.aba``, and MuJoCo (the same URDF, its RK4) stepped from Python, plain or copying out the
state a recording needs. Each constructor returns ``(None, reason)`` when its package is missing.
"""
from __future__ import annotations

import numpy as np

from .pinbridge import pin_model

#: step and publication rate of the real-time-factor runs (1 kHz RK4, 100 Hz joint states)
RTF_DT, RTF_RATE = 1e-3, 100.0


def pin_reference(model):
    """Pinocchio model and data of the exported URDF, or ``(None, reason)``."""
    try:
        import pinocchio as pin
    except ImportError:
        return None, 'pinocchio not installed'
    from ..model import to_urdf
    if model.has_spherical:   # URDF has no ball joint: JointModelSpherical, built directly
        pm = pin_model(model)[0]
    else:
        pm = pin.buildModelFromXML(to_urdf(model))
    return (pm, pm.createData()), ''


def pin_rk4_loop(pm, pd, q0, v0, damping, duration, dt=RTF_DT):
    """A Python RK4 loop over ``pin.aba`` (fixed-base, unforced: gravity and damping only)."""
    import pinocchio as pin
    aba = pin.aba
    q, v = q0.copy(), v0.copy()
    h2, h6 = 0.5 * dt, dt / 6.0
    add = (lambda q, dq: q + dq) if pm.nq == pm.nv else (lambda q, dq: pin.integrate(pm, q, dq))  # quaternions
    for _ in range(int(round(duration / dt))):
        a1 = aba(pm, pd, q, v, -damping * v)
        q2, v2 = add(q, h2 * v), v + h2 * a1
        a2 = aba(pm, pd, q2, v2, -damping * v2)
        q3, v3 = add(q, h2 * v2), v + h2 * a2
        a3 = aba(pm, pd, q3, v3, -damping * v3)
        q4, v4 = add(q, dt * v3), v + dt * a3
        a4 = aba(pm, pd, q4, v4, -damping * v4)
        q = add(q, h6 * (v + 2.0 * v2 + 2.0 * v3 + v4))
        v = v + h6 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
    return q, v


def mujoco_model(urdf, dt=RTF_DT):
    """MuJoCo model of a URDF with RK4 at step dt, or ``(None, reason)``."""
    try:
        import mujoco
    except ImportError:
        return None, 'mujoco not installed'
    # MuJoCo refuses zero principal moments (a slender bar's axial inertia): bound them at 1e-9 kg m²
    urdf = urdf.replace('<link ', '<mujoco><compiler boundinertia="1e-9"/></mujoco>\n  <link ', 1)
    try:
        m = mujoco.MjModel.from_xml_string(urdf)
    except Exception as e:  # MuJoCo's URDF importer refuses some files; say why
        return None, f'MuJoCo cannot load the URDF ({" ".join(str(e).split())})'
    m.opt.integrator = mujoco.mjtIntegrator.mjINT_RK4
    m.opt.timestep = dt
    return m, ''


def mujoco_loop(m, q0, v0, duration, nstep=1, rate=RTF_RATE):
    """Step MuJoCo from Python: ``nstep`` steps per call; reads qpos at every publication."""
    import mujoco
    d = mujoco.MjData(m)
    d.qpos[:] = q0
    d.qvel[:] = v0
    n = int(round(duration / m.opt.timestep))
    per_pub = max(1, int(round(1.0 / (rate * m.opt.timestep))))
    step = mujoco.mj_step
    if nstep == 1:
        for k in range(n):
            step(m, d)
            if (k + 1) % per_pub == 0:
                d.qpos.copy()
    else:
        for _ in range(n // nstep):
            step(m, d, nstep)
            d.qpos.copy()
    return d


def mujoco_recorded_loop(m, q0, v0, duration, rate=RTF_RATE):
    """MuJoCo RK4 from Python, ``mj_step(nstep)`` per publication period, its state (time, qpos,
    qvel, qacc, actuator forces) copied into preallocated arrays every period: a peer that also
    produces the data a recording needs (without encoding it)."""
    import mujoco
    d = mujoco.MjData(m)
    d.qpos[:] = q0
    d.qvel[:] = v0
    nstep = max(1, int(round(1.0 / (rate * m.opt.timestep))))
    n = int(round(duration * rate))
    T = np.empty(n)
    Q, V, A, F = (np.empty((n, m.nq)), np.empty((n, m.nv)), np.empty((n, m.nv)), np.empty((n, m.nv)))
    step = mujoco.mj_step
    for k in range(n):
        step(m, d, nstep)
        T[k] = d.time
        Q[k] = d.qpos
        V[k] = d.qvel
        A[k] = d.qacc
        F[k] = d.qfrc_actuator
    return Q
