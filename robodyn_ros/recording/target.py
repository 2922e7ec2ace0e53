"""Where a recording goes: checked before the simulation starts, never overwritten silently.

``robodyn run --record``, ``robodyn resim --record`` and the node's ``record`` parameter all call
:func:`check_record_path` first. It refuses, with one sentence naming the file and the way out:

* a file that exists (or, for the node, an episode file ``<stem>-<k>.mcap`` of an earlier run with
  the same name), unless overwriting was asked for (``--overwrite`` / ``overwrite:=true``);
* a path that is a directory, or the recording being re-simulated;
* a directory that cannot be created, or a file that cannot be written there (probed by opening
  it for appending; a probe file that did not exist is removed again).
"""
from __future__ import annotations

import glob
import os
import re

__all__ = ['RecordPathError', 'check_record_path', 'episode_files', 'episode_path']


class RecordPathError(ValueError):
    """A recording path that is refused; the message names the file and what to do."""


def episode_path(path: str, episode: int) -> str:
    """Recording file of the ``episode``-th reset: ``run.mcap`` -> ``run-1.mcap``, ... (0: ``path``)."""
    if episode == 0:
        return path
    root, ext = os.path.splitext(path)
    return f'{root}-{episode}{ext or ".mcap"}'


def episode_files(path: str) -> list[str]:
    """The files ``<stem>-<k><ext>`` (k = 1, 2, ...) that the node writes after ``~/reset``, as
    they exist now next to ``path``, in k order."""
    root, ext = os.path.splitext(path)
    ext = ext or '.mcap'
    pattern = re.compile(re.escape(os.path.basename(root)) + r'-([1-9][0-9]*)' + re.escape(ext) + '$')
    found = []
    for f in glob.glob(glob.escape(root) + '-*' + glob.escape(ext)):
        m = pattern.match(os.path.basename(f))
        if m:
            found.append((int(m.group(1)), f))
    return [f for _, f in sorted(found)]


def check_record_path(path: str, overwrite: bool = False, how_to_overwrite: str = '--overwrite',
                      also=(), source: str | None = None) -> str:
    """Refuse (:class:`RecordPathError`) a recording path before anything is simulated.

    path: the MCAP file to write; overwrite: replacing existing files is allowed; how_to_overwrite:
    the words that allow it, for the message (``--overwrite`` or ``overwrite:=true``); also: other
    files the run would write (episode files), refused like ``path`` when they exist; source: the
    recording being read (a re-simulation), which is never overwritten. Creates the parent
    directory. Returns ``path``.
    """
    full = os.path.abspath(path)
    if os.path.isdir(full):
        raise RecordPathError(f'{path}: is a directory; give a file name for the recording (e.g. {path}/run.mcap)')
    if source is not None and os.path.exists(full) and os.path.samefile(full, source):
        raise RecordPathError(f'{path}: is the recording being re-simulated; write the re-simulation to another file')
    existing = [f for f in [path, *also] if os.path.exists(f)]
    if existing and not overwrite:
        which = existing[0] if len(existing) == 1 else f'{existing[0]} (and {", ".join(existing[1:])})'
        raise RecordPathError(f'{which}: exists; refusing to overwrite it. Choose another file, or pass '
                              f'{how_to_overwrite} to replace it')
    parent = os.path.dirname(full)
    try:
        os.makedirs(parent, exist_ok=True)
    except OSError as e:
        raise RecordPathError(f'{path}: cannot create the directory {parent}: {e.strerror or e}') from None
    existed = os.path.exists(full)
    try:
        with open(full, 'ab'):
            pass
    except OSError as e:
        raise RecordPathError(f'{path}: cannot write the recording there: {e.strerror or e}') from None
    if not existed:
        os.remove(full)
    return path
