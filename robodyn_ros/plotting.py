"""Figures of a recording: one PNG of stacked panels chosen from what the recording contains.

Panels (:data:`PANELS`, in their default order) and where their data come from:

==============  ==========================================================================
``joints``      ``joint_states``: positions, velocities and applied efforts (= what the
                actuators applied), one row each for the arm joints and one row of three
                columns for the wheel joints, so that growing wheel angles do not flatten the
                arm's curves; the effort row is left out when every effort is zero (passive
                joints). Units from ``robot_description``: prismatic joints in m, m/s, N.
``path``        ``odom``: x–y path of base_link in odom, equal aspect, start/end markers
                with heading arrows.
``speed``       ``odom`` twist (base_link): forward speed v_x; v_y, v_z when not identically 0.
``yaw_rate``    ``odom`` twist (base_link): ω_z; ω_x, ω_y when not identically 0.
``currents``    ``diagnostics`` ``*_motor_current``; motor voltages (``wheel_voltage_commands``
                as commanded, ``*_motor_voltage`` as applied); electrical power and copper loss.
``energy``      ``diagnostics``: E and E0 + W_in; drift E − E0 − W_in (its relative value
                in the panel title).
``momentum``    ``diagnostics`` (free-flying systems): linear momentum, angular momentum about
                the CoM, and the CoM displacement c − c(t0) computed from ``com_*``.
``constraint``  ``diagnostics`` ``constraint_residual`` / ``constraint_velocity_residual``
                (log scale).
``wrenches``    ``constraint_wrenches/*``: |force| and |torque| of every joint/contact wrench.
``contacts``    ``contact_wrenches/*`` (a ground): vertical force F_z of every touching link and
                their sum (the ground's total reaction: m g at rest), and the horizontal
                force |F_xy| (friction on a level ground), world axes.
``stick``       ``/tf`` + ``/tf_static`` of a base in the x–z plane (``odom`` orientation a
                pure pitch, e.g. the diver): stick-figure snapshots (every link frame joined
                to its parent's, side view, every 0.1 s), and the somersault angle (odom
                pitch, unwrapped, in turns) against time.
==============  ==========================================================================

Diagnostics are recorded at their own (low, 1 Hz by default) rate, so those panels draw
markers at every sample. Topic names match with or without a namespace (``/ns/odom``).

Rendering is headless and reproducible: a :class:`matplotlib.figure.Figure` drawn by the Agg
canvas (no pyplot, no global backend switch), matplotlib's default style whatever the user's
matplotlibrc says, a fixed dpi, and no ``Software`` entry in the PNG metadata; equal recordings
give byte-identical PNGs with the same matplotlib version. matplotlib is imported only when a
figure is made, and its absence is reported as a :class:`PlotError` naming ``pip install
matplotlib``.
"""
from __future__ import annotations

import json
import math
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional

import numpy as np

__all__ = ['PANELS', 'DPI', 'WIDTH_IN', 'PlotError', 'UnreadableRecording', 'choose_panels', 'parse_panels',
           'recording_summary', 'load_recording', 'RecordingData', 'make_figure', 'plot_recording',
           'default_output', 'default_title']

#: every panel name, in the order panels are stacked by default
PANELS = ('joints', 'path', 'speed', 'yaw_rate', 'currents', 'energy', 'momentum', 'constraint', 'wrenches',
          'contacts', 'stick')
#: resolution of the PNG (dots per inch); fixed so the output does not depend on the machine
DPI = 100
#: figure width (inches); 12 in at 100 dpi = 1200 px
WIDTH_IN = 12.0
#: layout in inches: axes height of a row of time plots, largest height of the x–y path plot,
#: title block (plus TITLE_LINE_IN per title line), bottom margin, gap between rows (x labels +
#: next title), left margin (y labels), right margin (legends), gap between columns of a row.
#: Fixed, so every row lines up.
ROW_IN, PATH_IN, TITLE_IN, BOTTOM_IN, GAP_IN = 2.0, 4.5, 0.6, 0.55, 0.95
TITLE_LINE_IN = 0.27
LEFT_IN, RIGHT_IN, WSPACE_IN = 1.0, 2.3, 1.0
#: rc settings over matplotlib's defaults: short tick labels (scientific outside 1e-3..1e4)
_RC = {'axes.formatter.limits': (-3, 4), 'axes.formatter.use_mathtext': True}
#: smallest y span of a time plot: absolute (in the signal's SI unit) and relative to its level,
#: so that round-off noise draws flat
MIN_SPAN, MIN_RELATIVE_SPAN = 1e-9, 1e-3
#: a signal whose largest |value| is below this is "identically zero" (not drawn as an extra line)
ZERO_TOL = 1e-9
#: diagnostics series with fewer samples than this get a marker at every sample
MARKER_BELOW = 60

MATPLOTLIB_HINT = ('robodyn plot needs matplotlib, which is not installed: pip install matplotlib '
                   '(or: sudo apt install python3-matplotlib)')

# topic suffixes (relative names of the interface contract)
_JS, _ODOM, _DIAG, _VOLT, _DESC = 'joint_states', 'odom', 'diagnostics', 'wheel_voltage_commands', 'robot_description'
_WRENCH = 'constraint_wrenches/'
_CONTACT = 'contact_wrenches/'


class PlotError(ValueError):
    """Nothing (or not the requested panels) can be plotted, or matplotlib is missing."""


class UnreadableRecording(PlotError):
    """The input is missing or not an MCAP recording (no message could be read)."""


# -- choosing panels ------------------------------------------------------------------------------
def _find_topic(topics, name: str) -> Optional[str]:
    """The recorded topic for relative ``name``: ``/name`` if present, else the first ``/<ns>/name``."""
    if '/' + name in topics:
        return '/' + name
    hits = sorted(t for t in topics if t.endswith('/' + name))
    return hits[0] if hits else None


def _wrench_topics(topics, prefix=_WRENCH) -> List[str]:
    """Recorded ``constraint_wrenches/<name>`` topics (``contact_wrenches/<link>`` with prefix=_CONTACT), sorted."""
    return sorted(t for t in topics if ('/' + prefix) in t and not t.endswith('/' + prefix))


def _nonempty(summary: dict) -> Dict[str, dict]:
    """``summary['topics']`` without topics that have a channel but no message."""
    return {t: e for t, e in summary.get('topics', {}).items() if e.get('count', 1) > 0}


def choose_panels(summary: dict) -> List[str]:
    """The panels a recording supports, in :data:`PANELS` order.

    summary: :func:`robodyn_ros.recording.reader.summarize` output (``topics`` is used: topic ->
    ``{'count': ...}``), optionally with ``diagnostic_keys`` (the value names seen in
    ``diagnostics``, as :func:`recording_summary` adds). Without ``diagnostic_keys`` only the
    ``energy`` panel is inferred from a ``diagnostics`` topic (every simulator publishes energy);
    ``currents``, ``momentum`` and ``constraint`` need the keys.
    """
    topics = _nonempty(summary)
    keys = summary.get('diagnostic_keys')
    has_diag = _find_topic(topics, _DIAG) is not None
    out = []
    if _find_topic(topics, _JS):
        out.append('joints')
    if _find_topic(topics, _ODOM):
        out += ['path', 'speed', 'yaw_rate']
    if has_diag and keys is not None:
        keys = set(keys)
        if any(k.endswith('_motor_current') for k in keys):
            out.append('currents')
        if 'energy' in keys:
            out.append('energy')
        if any(k.startswith('momentum_') for k in keys):
            out.append('momentum')
        if 'constraint_residual' in keys or 'constraint_velocity_residual' in keys:
            out.append('constraint')
    elif has_diag:
        out.append('energy')
    if _wrench_topics(topics):
        out.append('wrenches')
    if _wrench_topics(topics, _CONTACT):
        out.append('contacts')
    return out   # 'stick' is added by plot_recording when the loaded odom is a pitch-only base


def parse_panels(spec: Optional[str]) -> Optional[List[str]]:
    """``'auto'``/None -> None; ``'joints,path'`` -> ``['joints', 'path']`` (validated, duplicates dropped).

    Raises PlotError naming the unknown panels and the valid names.
    """
    if spec is None or spec.strip() in ('', 'auto'):
        return None
    names = [s.strip() for s in spec.split(',') if s.strip()]
    bad = [n for n in names if n not in PANELS]
    if bad:
        raise PlotError(f'unknown panel(s) {", ".join(bad)}; choose from auto or {",".join(PANELS)}')
    return list(dict.fromkeys(names))


# -- loading --------------------------------------------------------------------------------------
@dataclass
class RecordingData:
    """Arrays of the plotted signals; times are simulation seconds (log time / 1e9).

    joint_*: (n, nj) in the order of ``joint_names`` (NaN where a message lacked a value);
    joint_types: name -> URDF type (from robot_description; missing when not recorded);
    odom_*: (n, 3) position in odom, (n,) yaw, (n, 3) linear and angular velocity in base_link;
    diag: key -> ((n,) times, (n,) values) for every numeric diagnostics value;
    voltage_t, voltage: commanded wheel voltages (n,), (n, 2); wrenches: name -> ((n,) t,
    (n, 3) force, (n, 3) torque); contacts: link -> the same, of ``contact_wrenches/<link>``.
    """

    path: str
    summary: dict
    joint_names: List[str] = field(default_factory=list)
    joint_types: Dict[str, str] = field(default_factory=dict)
    joint_t: np.ndarray = None
    joint_pos: np.ndarray = None
    joint_vel: np.ndarray = None
    joint_eff: np.ndarray = None
    odom_t: np.ndarray = None
    odom_xyz: np.ndarray = None
    odom_yaw: np.ndarray = None
    odom_q: np.ndarray = None
    odom_lin: np.ndarray = None
    odom_ang: np.ndarray = None
    diag: Dict[str, tuple] = field(default_factory=dict)
    voltage_t: np.ndarray = None
    voltage: np.ndarray = None
    wrenches: Dict[str, tuple] = field(default_factory=dict)
    contacts: Dict[str, tuple] = field(default_factory=dict)
    #: stick panel: times (n,), link name -> (n, 3) world positions of its frame, (parent, child) pairs
    tf_t: np.ndarray = None
    tf_pos: Dict[str, np.ndarray] = field(default_factory=dict)
    tf_edges: List[tuple] = field(default_factory=list)


def _number(text: str) -> Optional[float]:
    """A diagnostics value as float, or None for non-numbers (``'true'``, ``'rk4'``)."""
    try:
        return float(text)
    except (TypeError, ValueError):
        return None


def _diag_values(msg) -> Dict[str, float]:
    """Numeric key/values of every status of a DiagnosticArray (later statuses win on a clash)."""
    vals = {}
    for st in msg.status:
        for kv in st.values:
            x = _number(kv.value)
            if x is not None:
                vals[kv.key] = x
    return vals


def _urdf_joint_types(text: str) -> Dict[str, str]:
    """joint name -> URDF type (``revolute``, ``prismatic``, ``continuous``, ...); {} if unparsable."""
    try:
        root = ET.fromstring(text)
    except ET.ParseError:
        return {}
    return {j.get('name'): j.get('type', '') for j in root.iter('joint') if j.get('name')}


def _yaw(q) -> np.ndarray:
    """Yaw (rad) of (n, 4) quaternions (x, y, z, w): rotation of the body x axis about odom z."""
    x, y, z, w = q.T
    return np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def _rows(rows, width) -> np.ndarray:
    """(n, width) float array from ragged rows, NaN-padded."""
    a = np.full((len(rows), width), np.nan)
    for i, r in enumerate(rows):
        r = np.asarray(r, dtype=float)[:width]
        a[i, :r.size] = r
    return a


def recording_summary(path) -> dict:
    """:func:`~robodyn_ros.recording.reader.summarize` plus ``diagnostic_keys`` (sorted numeric keys)."""
    from .recording.reader import read_messages, summarize
    s = summarize(path)
    keys = set()
    diag = _find_topic(_nonempty(s), _DIAG)
    if diag:
        for _, _, _, msg in read_messages(path, topics=[diag]):
            keys.update(_diag_values(msg))
    s['diagnostic_keys'] = sorted(keys)
    return s


def _topics_for(panels, topics) -> List[str]:
    """The recorded topics the given panels read (plus robot_description for joint units)."""
    want = set()
    if 'joints' in panels:
        want.update(filter(None, [_find_topic(topics, _JS), _find_topic(topics, _DESC)]))
    if {'path', 'speed', 'yaw_rate'} & set(panels):
        want.update(filter(None, [_find_topic(topics, _ODOM)]))
    if {'currents', 'energy', 'momentum', 'constraint'} & set(panels):
        want.update(filter(None, [_find_topic(topics, _DIAG)]))
    if 'currents' in panels:
        want.update(filter(None, [_find_topic(topics, _VOLT)]))
    if 'wrenches' in panels:
        want.update(_wrench_topics(topics))
    if 'contacts' in panels:
        want.update(_wrench_topics(topics, _CONTACT))
    if 'stick' in panels and _find_topic(topics, _ODOM):
        want.update(filter(None, [_find_topic(topics, _ODOM), _find_topic(topics, 'tf'),
                                  _find_topic(topics, 'tf_static')]))
    return sorted(want)


def load_recording(path, panels=PANELS, summary: Optional[dict] = None) -> RecordingData:
    """Read what ``panels`` need from the recording at ``path`` in one pass.

    path: MCAP file; panels: panel names (default all); summary: its
    :func:`~robodyn_ros.recording.reader.summarize` output if already at hand. A truncated file
    is read up to its last complete chunk. Also fills ``summary['diagnostic_keys']``.
    """
    from .recording.reader import read_messages, summarize
    s = summary if summary is not None else summarize(path)
    topics = _nonempty(s)
    wanted = _topics_for(panels, topics)
    d = RecordingData(path=str(path), summary=s)
    js_t, js_name, js_p, js_v, js_e = [], None, [], [], []
    od = {'t': [], 'xyz': [], 'q': [], 'lin': [], 'ang': []}
    diag: Dict[str, tuple] = {}
    v_t, v_rows = [], []
    wr: Dict[str, tuple] = {}
    cw: Dict[str, tuple] = {}
    js_topic, od_topic, diag_topic = _find_topic(topics, _JS), _find_topic(topics, _ODOM), _find_topic(topics, _DIAG)
    volt_topic, desc_topic = _find_topic(topics, _VOLT), _find_topic(topics, _DESC)
    tf_topic, tfs_topic = _find_topic(topics, 'tf'), _find_topic(topics, 'tf_static')
    tf_static, tf_frames = {}, []
    for topic, _type, t_ns, msg in (read_messages(path, topics=wanted) if wanted else ()):
        t = t_ns * 1e-9
        if topic in (tf_topic, tfs_topic) and 'stick' in panels:
            rows = {tr.child_frame_id: (tr.header.frame_id, _tf_pose(tr.transform)) for tr in msg.transforms}
            if topic == tfs_topic:
                tf_static.update(rows)
            else:
                tf_frames.append((t, rows))
            continue
        if topic == js_topic:
            names = list(msg.name)
            if js_name is None:
                js_name = names
            if names == js_name:
                p, v, e = msg.position, msg.velocity, msg.effort
            else:  # reordered or partial message: map by name
                idx = {n: k for k, n in enumerate(names)}
                pick = (lambda arr: [arr[idx[n]] if n in idx and idx[n] < len(arr) else math.nan
                                     for n in js_name])
                p, v, e = pick(msg.position), pick(msg.velocity), pick(msg.effort)
            js_t.append(t)
            js_p.append(p)
            js_v.append(v)
            js_e.append(e)
        elif topic == od_topic:
            pp, tw = msg.pose.pose, msg.twist.twist
            od['t'].append(t)
            od['xyz'].append((pp.position.x, pp.position.y, pp.position.z))
            od['q'].append((pp.orientation.x, pp.orientation.y, pp.orientation.z, pp.orientation.w))
            od['lin'].append((tw.linear.x, tw.linear.y, tw.linear.z))
            od['ang'].append((tw.angular.x, tw.angular.y, tw.angular.z))
        elif topic == diag_topic:
            for k, x in _diag_values(msg).items():
                diag.setdefault(k, ([], []))
                diag[k][0].append(t)
                diag[k][1].append(x)
        elif topic == volt_topic:
            v_t.append(t)
            v_rows.append(msg.data)
        elif topic == desc_topic:
            d.joint_types = _urdf_joint_types(msg.data)
        elif topic in wanted:  # a constraint or contact wrench
            contact = ('/' + _CONTACT) in topic
            name = topic.split('/' + (_CONTACT if contact else _WRENCH), 1)[1]
            w = msg.wrench
            e = (cw if contact else wr).setdefault(name, ([], [], []))
            e[0].append(t)
            e[1].append((w.force.x, w.force.y, w.force.z))
            e[2].append((w.torque.x, w.torque.y, w.torque.z))
    if js_t:
        nj = len(js_name)
        d.joint_names = js_name
        d.joint_t = np.asarray(js_t)
        d.joint_pos, d.joint_vel, d.joint_eff = (_rows(r, nj) for r in (js_p, js_v, js_e))
    if od['t']:
        d.odom_t = np.asarray(od['t'])
        d.odom_xyz = np.asarray(od['xyz'], dtype=float)
        d.odom_q = np.asarray(od['q'], dtype=float)
        d.odom_yaw = np.unwrap(_yaw(d.odom_q))
        d.odom_lin = np.asarray(od['lin'], dtype=float)
        d.odom_ang = np.asarray(od['ang'], dtype=float)
    d.diag = {k: (np.asarray(tt), np.asarray(xx)) for k, (tt, xx) in sorted(diag.items())}
    if v_t:
        d.voltage_t = np.asarray(v_t)
        d.voltage = _rows(v_rows, max(len(r) for r in v_rows))
    d.wrenches, d.contacts = ({k: (np.asarray(a), np.asarray(b, dtype=float), np.asarray(c, dtype=float))
                               for k, (a, b, c) in sorted(x.items())} for x in (wr, cw))
    if diag_topic in wanted:
        s['diagnostic_keys'] = sorted(diag)
    if tf_frames:
        _stick_data(d, tf_frames, tf_static)
    return d


def _tf_pose(tr):
    """``(R (3, 3), p (3,))`` of a geometry_msgs/Transform."""
    from .spatial import quat_to_R
    r, p = tr.rotation, tr.translation
    return quat_to_R(np.array([r.x, r.y, r.z, r.w])), np.array([p.x, p.y, p.z])


def _stick_data(d: RecordingData, frames, static):
    """World (odom) positions of every TF frame at every /tf message, and the tree's edges."""
    d.tf_t = np.array([t for t, _ in frames])
    pos: Dict[str, list] = {}
    edges = set()
    for _, rows in frames:
        tree = {**static, **rows}
        cache = {}

        def world(name):
            if name not in tree:
                return np.eye(3), np.zeros(3)   # a root (odom)
            if name not in cache:
                parent, (R, p) = tree[name]
                Rp, pp = world(parent)
                cache[name] = (Rp @ R, Rp @ p + pp)
            return cache[name]
        for child, (parent, _) in tree.items():
            pos.setdefault(child, []).append(world(child)[1])
            edges.add((parent, child))
    d.tf_pos = {k: np.asarray(v) for k, v in pos.items() if len(v) == len(frames)}
    d.tf_edges = sorted(e for e in edges if e[0] in d.tf_pos and e[1] in d.tf_pos)


# -- drawing --------------------------------------------------------------------------------------
def _mpl():
    """(Figure, matplotlib.style) or PlotError with the install hint; attaches nothing global."""
    try:
        import matplotlib.style
        from matplotlib.figure import Figure
    except ImportError as e:
        raise PlotError(MATPLOTLIB_HINT) from e
    return Figure, matplotlib.style


def _colors(n):
    """n distinct colours: tab10, or tab20 beyond ten lines."""
    import matplotlib
    cmap = matplotlib.colormaps['tab10' if n <= 10 else 'tab20']
    return [cmap(k % cmap.N) for k in range(n)]


@dataclass
class _Row:
    """One row of axes: its height (in), one draw function per column ``draw(ax, last_column)``,
    and whether its x axis is simulation time (every time axis spans the recording's range)."""

    height: float
    draws: list
    time: bool = True


def _legend(ax, outside: bool, **kw):
    """Legend in the right margin (``outside``, the last column of a row) or inside the axes."""
    if not ax.get_legend_handles_labels()[0]:
        return
    if outside:
        ax.legend(loc='upper left', bbox_to_anchor=(1.02, 1.0), fontsize='small', borderaxespad=0.0,
                  frameon=False, **kw)
    else:
        ax.legend(loc='best', fontsize='small', framealpha=0.8, **kw)


def _decorate(ax, ylabel, title, floor: Optional[float] = MIN_SPAN):
    """Time-axis decoration: y label with units, x label, grid, title.

    floor: smallest y span, absolute; the span is also at least ``MIN_RELATIVE_SPAN`` of the
    level. So round-off noise around a constant (1e-18 rad/s about 0, 1e-15 about 5 rad/s)
    draws as the flat line it is instead of filling the axes. None: no floor (drift panels).
    """
    ax.set_ylabel(ylabel)
    ax.set_xlabel('simulation time (s)')
    ax.grid(True, alpha=0.3)
    ax.set_title(title, fontsize='medium')
    if floor:
        y0, y1 = ax.get_ylim()
        c = 0.5 * (y0 + y1)
        span = max(floor, MIN_RELATIVE_SPAN * abs(c))
        if y1 - y0 < span:
            ax.set_ylim(c - 0.5 * span, c + 0.5 * span)


def _diag_every(data) -> str:
    """`` (diagnostics every 1 s)``: the diagnostics sample period, for sparse panels' titles."""
    t = next((tt for tt in data.diag.values() if len(tt[0]) > 1), None)
    if t is None:
        return ' (one diagnostics sample)'
    return f' (diagnostics every {float(np.median(np.diff(t[0]))):.3g} s)'


def _diag_plot(ax, data, key, label, transform=None, **kw):
    """Plot one diagnostics series, markers on a thin dotted line when sparse; False if absent."""
    if key not in data.diag:
        return False
    t, x = data.diag[key]
    if transform is not None:
        x = transform(x)
    if len(t) < MARKER_BELOW:
        kw.setdefault('marker', 'o')
        kw.setdefault('markersize', 4)
        kw.setdefault('linestyle', ':')
        kw.setdefault('linewidth', 1.0)
    ax.plot(t, x, label=label, **kw)
    return True


def _styles(columns) -> List[str]:
    """Line style per curve: dashed when it repeats an earlier curve (left and right wheel), so
    that both stay visible; solid otherwise. columns: list of (n,) arrays."""
    out = []
    for k, y in enumerate(columns):
        same = any(y.shape == columns[j].shape and np.allclose(y, columns[j], rtol=1e-9, atol=1e-12,
                                                                 equal_nan=True) for j in range(k))
        out.append('--' if same else '-')
    return out


def _is_wheel(name: str, jtype: str) -> bool:
    """Wheel joints (continuous, or named like one) are drawn apart from the arm's."""
    return jtype == 'continuous' or 'wheel' in name


def _unit_text(names, types, rev: str, pri: str) -> str:
    """Unit text for a set of joints: ``rev`` (revolute), ``pri`` (prismatic) or both."""
    pris = {types.get(n) == 'prismatic' for n in names}
    if pris == {True}:
        return pri
    return f'{rev}; prismatic: {pri}' if True in pris else rev


def _rows_joints(data) -> List[_Row]:
    types, names = data.joint_types, data.joint_names
    cols = _colors(len(names))
    has_eff = data.joint_eff is not None and bool(np.any(np.nan_to_num(data.joint_eff) != 0.0))
    quantities = [('positions', 'position', data.joint_pos, 'rad', 'm'),
                  ('velocities', 'velocity', data.joint_vel, 'rad/s', 'm/s')]
    if has_eff:
        quantities.append(('applied efforts', 'effort', data.joint_eff, 'N·m', 'N'))
    arm = [k for k, n in enumerate(names) if not _is_wheel(n, types.get(n, ''))]
    wheels = [k for k, n in enumerate(names) if _is_wheel(n, types.get(n, ''))]
    note = '' if has_eff else ' (applied efforts all zero: not drawn)'

    def draw(idx, what, qty, arr, rev, pri, who, ncol_legend=1):
        gnames = [names[k] for k in idx]
        mixed = len({types.get(n) == 'prismatic' for n in gnames}) > 1

        def _draw(ax, last):
            for k, ls in zip(idx, _styles([arr[:, k] for k in idx])):
                unit = pri if types.get(names[k]) == 'prismatic' else rev
                ax.plot(data.joint_t, arr[:, k], color=cols[k], linestyle=ls,
                        label=f'{names[k]} ({unit})' if mixed else names[k])
            _decorate(ax, f'{qty} ({_unit_text(gnames, types, rev, pri)})', f'{who} {what}')
            if last:
                _legend(ax, True, ncol=ncol_legend)
        return _draw

    rows = []
    if arm:
        ncol = 1 if len(arm) <= 12 else 2
        for i, (what, qty, arr, rev, pri) in enumerate(quantities):
            rows.append(_Row(ROW_IN, [draw(arm, what, qty, arr, rev, pri, 'joint', ncol)]))
        if note:
            _append_title(rows[-1], note)
    if wheels:
        rows.append(_Row(ROW_IN, [draw(wheels, what, qty, arr, rev, pri, 'wheel')
                                  for what, qty, arr, rev, pri in quantities]))
    return rows


def _append_title(row: _Row, note: str):
    """Wrap the last draw function of ``row`` so that its title ends with ``note``."""
    inner = row.draws[-1]

    def _draw(ax, last):
        inner(ax, last)
        ax.set_title(ax.get_title() + note, fontsize='medium')
    row.draws[-1] = _draw


def _heading_arrow(ax, x, y, yaw, color, length):
    """Arrow of ``length`` from (x, y) along ``yaw``; its tip counts in the data limits."""
    ax.update_datalim([(x + length * math.cos(yaw), y + length * math.sin(yaw))])
    ax.annotate('', xy=(x + length * math.cos(yaw), y + length * math.sin(yaw)), xytext=(x, y),
                arrowprops={'arrowstyle': '-|>', 'color': color, 'lw': 1.8, 'mutation_scale': 14}, zorder=4)


def _path_height(data) -> float:
    """Height of the path axes: the path's y/x aspect over the axes width, within [ROW_IN, PATH_IN]."""
    w = WIDTH_IN - LEFT_IN - RIGHT_IN
    x, y = data.odom_xyz[:, 0], data.odom_xyz[:, 1]
    px, py = float(np.ptp(x)), float(np.ptp(y))
    aspect = py / px if px > 0 else 1.0
    return float(np.clip(w * aspect * 1.15, ROW_IN, PATH_IN))


def _rows_path(data) -> List[_Row]:
    def _draw(ax, last):
        x, y, yaw = data.odom_xyz[:, 0], data.odom_xyz[:, 1], data.odom_yaw
        ax.plot(x, y, color='tab:blue', lw=1.5, label='base_link path', zorder=2)
        ax.plot(x[0], y[0], 'o', color='tab:green', ms=8, label=f'start (t = {data.odom_t[0]:g} s)', zorder=3)
        ax.plot(x[-1], y[-1], 's', color='tab:red', ms=8, label=f'end (t = {data.odom_t[-1]:g} s)', zorder=3)
        span = max(float(np.ptp(x)), float(np.ptp(y)), 1e-3)
        _heading_arrow(ax, x[0], y[0], yaw[0], 'tab:green', 0.1 * span)
        _heading_arrow(ax, x[-1], y[-1], yaw[-1], 'tab:red', 0.1 * span)
        ax.autoscale_view()
        ax.set_aspect('equal', adjustable='datalim')
        ax.set_xlabel('x in odom (m)')
        ax.set_ylabel('y in odom (m)')
        ax.grid(True, alpha=0.3)
        dist = float(np.sum(np.hypot(np.diff(x), np.diff(y))))
        ax.set_title(f'x–y path of base_link (arrows: heading); travelled {dist:.4g} m, '
                     f'yaw change {math.degrees(yaw[-1] - yaw[0]):.3g}°', fontsize='medium')
        _legend(ax, last)
    return [_Row(_path_height(data), [_draw], time=False)]


def _components(ax, t, arr, names):
    """Plot column 0 always, columns 1 and 2 only when not identically zero."""
    ax.plot(t, arr[:, 0], label=names[0])
    for k in (1, 2):
        if np.nanmax(np.abs(arr[:, k])) > ZERO_TOL:
            ax.plot(t, arr[:, k], label=names[k], lw=1.0)


def _rows_speed(data) -> List[_Row]:
    def _draw(ax, last):
        _components(ax, data.odom_t, data.odom_lin, ['forward speed v_x', 'v_y', 'v_z'])
        _decorate(ax, 'speed (m/s)', 'base_link velocity in base_link')
        _legend(ax, last)
    return [_Row(ROW_IN, [_draw])]


def _rows_yaw_rate(data) -> List[_Row]:
    def _draw(ax, last):
        ax.set_prop_cycle(color=['tab:purple', 'tab:olive', 'tab:cyan'])
        ang = data.odom_ang[:, [2, 0, 1]]  # z first: the yaw rate is the one always drawn
        _components(ax, data.odom_t, ang, ['yaw rate ω_z', 'ω_x', 'ω_y'])
        _decorate(ax, 'angular rate (rad/s)', 'base_link angular velocity in base_link')
        _legend(ax, last)
    return [_Row(ROW_IN, [_draw])]


def _side(key: str, suffix: str) -> str:
    return key[:-len(suffix)] or key


def _rows_currents(data) -> List[_Row]:
    every = _diag_every(data)
    cur = [k for k in data.diag if k.endswith('_motor_current')]
    volt = [k for k in data.diag if k.endswith('_motor_voltage')]
    power = [k for k in ('electrical_power', 'copper_loss') if k in data.diag]
    cols = _colors(max(len(cur), len(volt), 2))

    def _currents(ax, last):
        for j, k in enumerate(cur):
            _diag_plot(ax, data, k, _side(k, '_motor_current'), color=cols[j])
        _decorate(ax, 'current (A)', 'motor currents' + every)
        _legend(ax, last)

    def _voltages(ax, last):
        if data.voltage is not None:
            nv = data.voltage.shape[1]
            for j in range(nv):
                side = ('left', 'right')[j] if nv == 2 else f'motor {j}'
                ax.plot(data.voltage_t, data.voltage[:, j], drawstyle='steps-post', color=cols[j % len(cols)],
                        alpha=0.8, label=f'{side} commanded')
        for j, k in enumerate(volt):
            _diag_plot(ax, data, k, f'{_side(k, "_motor_voltage")} applied', color=cols[j % len(cols)],
                       linestyle='none', marker='x', markersize=6)
        _decorate(ax, 'voltage (V)', 'motor voltages')
        _legend(ax, last)

    def _power(ax, last):
        for k in power:
            _diag_plot(ax, data, k, k.replace('_', ' '))
        _decorate(ax, 'power (W)', 'electrical power')
        _legend(ax, last)

    draws = [_currents] + ([_voltages] if volt or data.voltage is not None else []) + ([_power] if power else [])
    return [_Row(ROW_IN, draws)]


def _rows_energy(data) -> List[_Row]:
    every = _diag_every(data)

    def _energy(ax, last):
        _diag_plot(ax, data, 'energy', 'E', color='tab:blue', linewidth=2.0)
        if 'energy' in data.diag and 'work_in' in data.diag:
            (t, e), (tw, w) = data.diag['energy'], data.diag['work_in']
            if np.array_equal(t, tw):
                # E0 from the first sample, E0 = E - W_in - drift, also when the recording started late
                drift = data.diag.get('energy_drift')
                e0 = e[0] - w[0] - (drift[1][0] if drift is not None and np.array_equal(drift[0], t) else 0.0)
                _diag_plot(ax, data, 'work_in', 'E0 + W_in', transform=lambda w: e0 + w, color='tab:orange',
                           linestyle='--', marker='none' if len(t) >= MARKER_BELOW else 'x')
        _decorate(ax, 'energy (J)', 'total energy' + every)
        _legend(ax, last)

    def _drift(ax, last):
        _diag_plot(ax, data, 'energy_drift', 'E − E0 − W_in', color='tab:red')
        rel = data.diag.get('energy_drift_relative')
        worst = f' (max relative {np.nanmax(np.abs(rel[1])):.2g})' if rel is not None and len(rel[1]) else ''
        _decorate(ax, 'drift (J)', 'energy drift' + worst, floor=None)
        _legend(ax, last)
    return [_Row(ROW_IN, [_energy, _drift])]


def _rows_momentum(data) -> List[_Row]:
    def column(prefix, ylabel, title, relative=False):
        def _draw(ax, last):
            for comp in 'xyz':
                _diag_plot(ax, data, prefix + comp, comp, transform=(lambda x: x - x[0]) if relative else None)
            _decorate(ax, ylabel, title, floor=None)
            if last:
                _legend(ax, True)
        return _draw
    every = _diag_every(data)
    return [_Row(ROW_IN, [column('momentum_linear_', 'p (kg·m/s)', 'linear momentum' + every),
                          column('momentum_angular_com_', 'L (kg·m²/s)', 'angular momentum about CoM'),
                          column('com_', 'c − c(t0) (m)', 'CoM drift', relative=True)])]


def _rows_constraint(data) -> List[_Row]:
    def _draw(ax, last):
        pos_level = 'constraint_velocity_residual' in data.diag
        series = [('constraint_residual', 'position max |φ| (m)' if pos_level
                   else 'rolling max |K v| (m/s)'),
                  ('constraint_velocity_residual', 'velocity max |φ̇| (m/s)')]
        zero = []
        for key, label in series:
            if key not in data.diag:
                continue
            x = np.abs(data.diag[key][1])
            if not np.any(x > 0):
                zero.append(label.split(' max')[0])
                continue
            _diag_plot(ax, data, key, label, transform=lambda x: np.where(np.abs(x) > 0, np.abs(x), np.nan))
        if ax.lines:
            ax.set_yscale('log')
        note = f'; {" and ".join(zero)} residual exactly 0' if zero else ''
        _decorate(ax, 'residual (m, m/s)', 'constraint residual' + _diag_every(data) + note, floor=None)
        _legend(ax, last)
    return [_Row(ROW_IN, [_draw])]


def _rows_wrenches(data) -> List[_Row]:
    names = list(data.wrenches)
    cols = _colors(len(names))

    def column(k, ylabel, title):
        def _draw(ax, last):
            mags = [np.linalg.norm(data.wrenches[name][1 + k], axis=1) for name in names]
            for c, name, y, ls in zip(cols, names, mags, _styles(mags)):
                ax.plot(data.wrenches[name][0], y, color=c, linestyle=ls, label=name)
            _decorate(ax, ylabel, title)
            if last:
                _legend(ax, True, ncol=1 if len(names) <= 12 else 2)
        return _draw
    return [_Row(ROW_IN, [column(0, '|force| (N)', 'constraint wrenches: force magnitude'),
                          column(1, '|torque| (N·m)', 'constraint wrenches: torque magnitude')])]


def _rows_contacts(data) -> List[_Row]:
    names = list(data.contacts)
    if not names:
        return []   # no ground in this recording
    cols = _colors(len(names))

    def vertical(ax, last):
        ys = [data.contacts[n][1][:, 2] for n in names]
        for c, name, y, ls in zip(cols, names, ys, _styles(ys)):
            ax.plot(data.contacts[name][0], y, color=c, linestyle=ls, label=name)
        t = data.contacts[names[0]][0]
        if len(names) > 1 and all(len(data.contacts[n][0]) == len(t) for n in names):
            ax.plot(t, np.sum(ys, axis=0), color='k', lw=1.4, linestyle='--', label='sum')
        _decorate(ax, 'F_z (N)', 'ground reaction: vertical force per link')
        if last:
            _legend(ax, True, ncol=1 if len(names) <= 12 else 2)

    def horizontal(ax, last):
        for c, name in zip(cols, names):
            ax.plot(data.contacts[name][0], np.linalg.norm(data.contacts[name][1][:, :2], axis=1), color=c, label=name)
        _decorate(ax, '|F_xy| (N)', 'ground reaction: horizontal force per link')
    return [_Row(ROW_IN, [vertical, horizontal])]


def _pitch_only(data) -> bool:
    """Is the recorded odom orientation a rotation about y only (a base in the x–z plane)?"""
    return data.odom_q is not None and bool(np.abs(data.odom_q[:, [0, 2]]).max() < 1e-9) and \
        bool(np.abs(data.odom_xyz[:, 1]).max() < 1e-9)


def _rows_stick(data) -> List[_Row]:
    if not _has_data('stick', data):
        return []   # no TF, or not a base in the x-z plane
    pitch = np.unwrap(2.0 * np.arctan2(data.odom_q[:, 1], data.odom_q[:, 3]))

    def _figure(ax, last):
        t = data.tf_t
        picks = sorted({int(k) for k in np.searchsorted(t, np.arange(t[0], t[-1] + 1e-9, 0.1))} | {len(t) - 1})
        picks = [k for k in picks if k < len(t)]
        cmap = _mpl_cmap('viridis')
        parents = {a for a, _ in data.tf_edges}
        leaves = [f for f in data.tf_pos if f != 'odom' and f not in parents]
        for n, k in enumerate(picks):
            c = cmap(n / max(len(picks) - 1, 1))
            for a, b in data.tf_edges:
                pa, pb = data.tf_pos[a][k], data.tf_pos[b][k]
                ax.plot([pa[0], pb[0]], [pa[2], pb[2]], color=c, lw=1.6, solid_capstyle='round')
            ax.plot([data.tf_pos[f][k][0] for f in leaves], [data.tf_pos[f][k][2] for f in leaves], 'o', color=c,
                    ms=3)
        ax.plot(data.odom_xyz[:, 0], data.odom_xyz[:, 2], color='0.6', lw=0.8, ls='--', label='base_link path')
        ax.set_aspect('equal', adjustable='datalim')
        ax.set_xlabel('x in odom (m)')
        ax.set_ylabel('z in odom (m)')
        ax.grid(True, alpha=0.3)
        ax.set_title(f'stick figure every 0.1 s (t = {t[picks[0]]:g} … {t[picks[-1]]:g} s, dark → light)',
                     fontsize='medium')

    def _angle(ax, last):
        turns = pitch / (2.0 * np.pi)
        ax.plot(data.odom_t, turns, color='tab:purple', label='base pitch')
        ax.set_xlabel('time (s)')
        ax.set_ylabel('somersault angle (turns)')
        ax.grid(True, alpha=0.3)
        ax.set_title(f'somersault angle: {turns[-1]:.4f} turns at t = {data.odom_t[-1]:g} s', fontsize='medium')
        ax.set_xlim(data.odom_t[0], data.odom_t[-1])
    return [_Row(PATH_IN * 1.6, [_figure, _angle], time=False)]


def _mpl_cmap(name):
    import matplotlib
    return matplotlib.colormaps[name]


_ROWS = {'joints': _rows_joints, 'path': _rows_path, 'speed': _rows_speed, 'yaw_rate': _rows_yaw_rate,
         'currents': _rows_currents, 'energy': _rows_energy, 'momentum': _rows_momentum,
         'constraint': _rows_constraint, 'wrenches': _rows_wrenches, 'contacts': _rows_contacts, 'stick': _rows_stick}


def _has_data(panel: str, data: RecordingData) -> bool:
    """Does ``data`` hold what ``panel`` draws?"""
    if panel == 'joints':
        return data.joint_t is not None and bool(data.joint_names)
    if panel in ('path', 'speed', 'yaw_rate'):
        return data.odom_t is not None
    if panel == 'currents':
        return any(k.endswith('_motor_current') for k in data.diag)
    if panel == 'energy':
        return 'energy' in data.diag
    if panel == 'momentum':
        return any(k.startswith('momentum_') for k in data.diag)
    if panel == 'constraint':
        return 'constraint_residual' in data.diag or 'constraint_velocity_residual' in data.diag
    if panel == 'stick':
        return data.tf_t is not None and data.odom_t is not None and _pitch_only(data)
    if panel == 'contacts':
        return bool(data.contacts)
    return bool(data.wrenches)


def default_title(data: RecordingData) -> str:
    """``scene — file`` and a line with integrator settings and the time range."""
    s = data.summary
    md = s.get('metadata', {}).get('robodyn', {})
    head = f'{md.get("scene_name") or "recording"} — {os.path.basename(data.path)}'
    bits = []
    try:
        st = json.loads(md.get('settings') or '{}')
    except ValueError:
        st = {}
    if st.get('integrator'):
        integ = st['integrator']
        if st.get('rtol') is not None:
            integ += f' rtol {st["rtol"]:g} atol {st.get("atol", float("nan")):g}'
        elif st.get('dt') is not None:
            integ += f' dt {st["dt"]:g} s'
        bits.append(integ)
    if s.get('start_time_ns') is not None:
        bits.append(f'sim time {s["start_time_ns"] * 1e-9:g}–{s["end_time_ns"] * 1e-9:g} s')
    bits.append(f'{s.get("message_count", 0)} messages')
    if not s.get('finished', True):
        bits.append('NOT finished cleanly: ' + (s.get('error') or 'no footer'))
    return head + '\n' + ', '.join(bits)


def _layout_rows(data: RecordingData, panels) -> List[_Row]:
    return [row for p in panels for row in _ROWS[p](data)]


def make_figure(data: RecordingData, panels, title: Optional[str] = None):
    """A matplotlib Figure (Agg canvas) with the panels' rows stacked top to bottom.

    data: from :func:`load_recording`; panels: names, each of which must have data
    (:func:`choose_panels`); title: figure title (default :func:`default_title`). The layout is
    fixed in inches (:data:`ROW_IN`, :data:`LEFT_IN`, ...), so the axes of every row line up and
    legends sit in the right margin; every time axis spans the recording's time range.
    """
    Figure, _ = _mpl()
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    rows = _layout_rows(data, panels)
    heights = [r.height for r in rows]
    title = title if title is not None else default_title(data)
    top = TITLE_IN + TITLE_LINE_IN * len(title.splitlines() or [''])
    H = top + BOTTOM_IN + sum(heights) + GAP_IN * (len(rows) - 1)
    fig = Figure(figsize=(WIDTH_IN, H), dpi=DPI)
    FigureCanvasAgg(fig)
    fig.suptitle(title, fontsize='large', y=1.0 - 0.12 / H, va='top')
    grid = fig.add_gridspec(len(rows), 1, height_ratios=heights, left=LEFT_IN / WIDTH_IN,
                            right=1.0 - RIGHT_IN / WIDTH_IN, top=1.0 - top / H, bottom=BOTTOM_IN / H,
                            hspace=GAP_IN / float(np.mean(heights)))
    col_w = WIDTH_IN - LEFT_IN - RIGHT_IN
    s = data.summary
    t0, t1 = s.get('start_time_ns'), s.get('end_time_ns')
    for k, row in enumerate(rows):
        n = len(row.draws)
        w = (col_w - WSPACE_IN * (n - 1)) / n
        sub = grid[k, 0].subgridspec(1, n, wspace=WSPACE_IN / w)
        for c, draw in enumerate(row.draws):
            ax = fig.add_subplot(sub[0, c])
            draw(ax, c == n - 1)
            if row.time and t0 is not None and t1 > t0:
                # not sharex: each axis keeps a tick density fitting its own width
                pad = 0.015 * (t1 - t0) * 1e-9
                ax.set_xlim(t0 * 1e-9 - pad, t1 * 1e-9 + pad)
    return fig


def default_output(path) -> Path:
    """``IN.mcap`` -> ``IN.png`` (same directory)."""
    return Path(path).with_suffix('.png')


def plot_recording(path, out=None, panels=None, title: Optional[str] = None):
    """Read a recording and write its PNG; returns ``(output path, panels drawn, skipped panels)``.

    path: MCAP file; out: PNG path (default :func:`default_output`); panels: names to draw in
    that order, or None/'auto' for :func:`choose_panels`; requested panels without data are
    skipped and returned as ``skipped``. title: figure title (default: scene, file, settings).
    Raises UnreadableRecording (a PlotError) when the file is missing or not MCAP, PlotError
    when there is nothing to plot or matplotlib is missing, OSError when the PNG cannot be
    written.
    """
    from .recording.reader import summarize
    _mpl()  # fail before reading a long recording
    if isinstance(panels, str):
        panels = parse_panels(panels)
    if not os.path.isfile(path):
        raise UnreadableRecording(f'{path}: no such file')
    s = summarize(path)
    if s['message_count'] == 0 and s['error']:
        raise UnreadableRecording(f'{path}: not a readable MCAP recording ({s["error"]})')
    data = load_recording(path, panels or PANELS, summary=s)
    if panels is None:
        chosen = [p for p in choose_panels(s) if _has_data(p, data)]
        if _has_data('stick', data):   # a base in the x-z plane: its stick figure first
            chosen = ['stick'] + [p for p in chosen if p not in ('path', 'yaw_rate')]
        skipped = []
    else:
        chosen = [p for p in panels if _has_data(p, data)]
        skipped = [p for p in panels if p not in chosen]
    if not chosen:
        have = ', '.join(sorted(_nonempty(s))) or 'no messages'
        what = ('any of the requested panels (' + ','.join(panels) + ')') if panels else 'anything'
        raise PlotError(f'{path}: nothing to plot: no data for {what}; the plotted topics are joint_states, '
                        f'odom, diagnostics, constraint_wrenches/*, and the recording has: {have}')
    _, style = _mpl()
    out = Path(out) if out is not None else default_output(path)
    if out.parent and not out.parent.exists():
        out.parent.mkdir(parents=True, exist_ok=True)
    with style.context(['default', _RC]):
        fig = make_figure(data, chosen, title)
        fig.savefig(out, format='png', dpi=DPI, metadata={'Software': None})
    return out, chosen, skipped
