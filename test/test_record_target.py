"""A recording never overwrites a file silently, and a path it cannot write is refused before the run.

``robodyn run --record``, ``robodyn resim --record`` and the node's ``record`` parameter: an
existing file is refused with a message naming ``--overwrite`` / ``overwrite:=true`` (the file is
left as it was, nothing is simulated); with the flag it is replaced; a directory that cannot be
created (a path through a regular file) and the recording being re-simulated are refused too.
"""
from __future__ import annotations

import re
from pathlib import Path

import pytest
from ros_helpers import REPO, Domain, start_sim

from robodyn_ros.cli import main as robodyn
from robodyn_ros.recording import summarize
from robodyn_ros.recording.target import RecordPathError, check_record_path, episode_files

KEEP = b'an earlier recording: keep me\n'


def _is_mcap(path) -> bool:
    s = summarize(path)
    return s['finished'] and s['topics']['/joint_states']['count'] > 0


def test_check_record_path_refuses_and_allows(tmp_path):
    new = tmp_path / 'sub' / 'dir' / 'new.mcap'
    assert check_record_path(str(new)) == str(new)
    assert new.parent.is_dir() and not new.exists()   # the directory is made, the probe file removed
    old = tmp_path / 'old.mcap'
    old.write_bytes(KEEP)
    with pytest.raises(RecordPathError, match=r'old\.mcap: exists; refusing to overwrite it.*--overwrite'):
        check_record_path(str(old))
    assert check_record_path(str(old), overwrite=True) == str(old) and old.read_bytes() == KEEP
    with pytest.raises(RecordPathError, match='is a directory'):
        check_record_path(str(tmp_path), overwrite=True)
    blocker = tmp_path / 'a_file'
    blocker.write_bytes(b'')
    with pytest.raises(RecordPathError, match=r'cannot create the directory .*a_file'):
        check_record_path(str(blocker / 'x.mcap'))
    with pytest.raises(RecordPathError, match='is the recording being re-simulated'):
        check_record_path(str(old), overwrite=True, source=str(old))
    # the node's episode files: run.mcap -> run-1.mcap, run-2.mcap (not run-x.mcap, not run-0.mcap)
    for name in ('run-2.mcap', 'run-1.mcap', 'run-x.mcap', 'run-0.mcap', 'run-10.mcap'):
        (tmp_path / name).write_bytes(KEEP)
    run = str(tmp_path / 'run.mcap')
    assert episode_files(run) == [str(tmp_path / f'run-{k}.mcap') for k in (1, 2, 10)]
    with pytest.raises(RecordPathError, match=r'run-1\.mcap \(and .*run-2\.mcap.*\): exists.*overwrite:=true'):
        check_record_path(run, how_to_overwrite='overwrite:=true', also=episode_files(run))


def test_robodyn_run_refuses_an_existing_file_before_running_and_overwrites_when_asked(tmp_path, capsys):
    out = tmp_path / 'run.mcap'
    out.write_bytes(KEEP)
    assert robodyn(['run', 'stanford_arm', '--duration', '0.05', '--record', str(out)]) == 2
    cap = capsys.readouterr()
    assert f'robodyn run: {out}: exists; refusing to overwrite it' in cap.err and '--overwrite' in cap.err
    assert cap.out == ''                  # no run summary: nothing was simulated
    assert out.read_bytes() == KEEP
    assert robodyn(['run', 'stanford_arm', '--duration', '0.05', '--record', str(out), '--overwrite']) == 0
    assert _is_mcap(out)
    capsys.readouterr()
    blocked = tmp_path / 'plain_file'
    blocked.write_bytes(b'')
    assert robodyn(['run', 'stanford_arm', '--duration', '0.05', '--record', str(blocked / 'x.mcap')]) == 2
    cap = capsys.readouterr()
    assert 'cannot create the directory' in cap.err and 'Traceback' not in cap.err and cap.out == ''


def test_robodyn_resim_refuses_an_existing_file_and_its_own_input(tmp_path, capsys):
    src = tmp_path / 'src.mcap'
    assert robodyn(['run', 'stanford_arm', '--duration', '0.05', '--record', str(src)]) == 0
    src_bytes = src.read_bytes()
    out = tmp_path / 'resim.mcap'
    out.write_bytes(KEEP)
    capsys.readouterr()
    assert robodyn(['resim', str(src), '--record', str(out)]) == 2
    err = capsys.readouterr().err
    assert f'robodyn resim: {out}: exists; refusing to overwrite it' in err and '--overwrite' in err
    assert out.read_bytes() == KEEP
    assert robodyn(['resim', str(src), '--record', str(src), '--overwrite']) == 2
    assert 'is the recording being re-simulated' in capsys.readouterr().err
    assert src.read_bytes() == src_bytes
    assert robodyn(['resim', str(src), '--record', str(out), '--overwrite']) == 0
    assert _is_mcap(out)


@pytest.mark.processes
def test_node_refuses_an_existing_record_file_and_replaces_it_with_overwrite(tmp_path):
    """The node exits 2 at start (before any simulation) naming overwrite:=true; with it, it runs
    and replaces the file, twice in a row, as ``make run`` does."""
    rec = tmp_path / 'node.mcap'
    rec.write_bytes(KEEP)
    params = {'scene': 'stanford_arm', 'mode': 'max', 'scripted_commands': True, 'duration': 0.1,
              'record': str(rec), 'publish_tf': False}
    dom = Domain()
    try:
        node = start_sim(dom, params, tmp_path / 'refused.log')
        try:
            rc = node.wait(timeout=60)
        finally:
            node.cleanup()
        log = node.output()
        assert rc == 2, log
        assert f"parameter 'record': {rec}: exists; refusing to overwrite it" in log and 'overwrite:=true' in log
        assert rec.read_bytes() == KEEP
        for k in range(2):
            node = start_sim(dom, {**params, 'overwrite': True}, tmp_path / f'ok{k}.log')
            try:
                rc = node.wait(timeout=90)
            finally:
                node.cleanup()
            assert rc == 0, node.output()
            assert _is_mcap(rec)
    finally:
        dom.release()


def test_make_run_replaces_its_recording():
    """``make run`` records to a fixed path: it passes overwrite:=true so a second run works."""
    text = Path(REPO, 'Makefile').read_text()
    run = re.search(r'^run:.*\n((?:\t.*\n)+)', text, re.M)
    assert run, 'no run target'
    recipe = run.group(1)
    assert 'record:=runs/stanford_arm.mcap' in recipe and '-p overwrite:=true' in recipe


def test_node_overwrite_parameter_is_declared_documented_and_validated(tmp_path):
    from robodyn_ros.nodes.sim import PARAMETERS, ConfigError, resolve_config
    from robodyn_ros.scene import load_scene
    assert PARAMETERS['overwrite'][0] is False
    assert 'overwrite: false' in Path(REPO, 'config', 'sim.yaml').read_text()
    scene = load_scene('stanford_arm')
    raw = {k: default for k, (default, _) in PARAMETERS.items()}
    rec = tmp_path / 'r.mcap'
    rec.write_bytes(KEEP)
    with pytest.raises(ConfigError, match="parameter 'overwrite' must be true or false"):
        resolve_config({**raw, 'record': str(rec), 'overwrite': 'yes'}, scene)
    with pytest.raises(ConfigError, match=r"parameter 'record': .*r\.mcap: exists"):
        resolve_config({**raw, 'record': str(rec)}, scene)
    assert resolve_config({**raw, 'record': str(rec), 'overwrite': True}, scene).record == str(rec)
    assert rec.read_bytes() == KEEP   # checked, not touched, before the run
