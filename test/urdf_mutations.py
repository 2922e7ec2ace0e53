"""Seeded mutations of real URDF files for the fuzz test (test_urdf_fuzz.py): each returns the
mutated text and a short description of what was done."""
from __future__ import annotations

import random
import re

#: example-robot-data files the fuzz test mutates (small and varied: fixed and floating bases,
#: fixed joints, limits, damping, mimic joints, effort="0", sensors with made-up inertias)
FILES = ['double_pendulum_description/urdf/double_pendulum_simple.urdf',
         'ur_description/urdf/ur5_robot.urdf',
         'panda_description/urdf/panda.urdf',
         'solo_description/robots/solo12.urdf',
         'iris_description/robots/iris_simple.urdf',
         'so_arm_description/urdf/so101.urdf']

_NUMBERS = ['nan', 'inf', '-inf', '1e308', '-1e308', '1e-320', '0', '-1', '', 'abc', '1e30', '-0', '1 2']
_ATTR = re.compile(r'(\s)([A-Za-z_]+)="([^"]*)"')
_TAG = re.compile(r'<(link|joint|inertial|mass|inertia|origin|axis|limit|parent|child|dynamics|mimic|visual)\b')


def _names(text, tag):
    return re.findall(rf'<{tag}\s[^>]*?name="([^"]*)"', text)


def _attr_spans(text):
    return [m for m in _ATTR.finditer(text)]


def delete_attribute(text, rng):
    m = rng.choice(_attr_spans(text))
    return text[:m.start()] + ' ' + text[m.end():], f'deleted {m.group(2)}="{m.group(3)[:20]}"'


def bad_number(text, rng):
    ms = [m for m in _attr_spans(text) if m.group(2) in ('value', 'xyz', 'rpy', 'ixx', 'iyy', 'izz', 'ixy', 'ixz',
                                                         'iyz', 'effort', 'velocity', 'lower', 'upper', 'damping',
                                                         'friction', 'multiplier', 'offset')]
    m = rng.choice(ms)
    vals = m.group(3).split() or ['0']
    vals[rng.randrange(len(vals))] = rng.choice(_NUMBERS)
    new = ' '.join(vals)
    return text[:m.start(3)] + new + text[m.end(3):], f'{m.group(2)}="{new}"'


def negative_mass(text, rng):
    ms = list(re.finditer(r'<mass\s+value="([^"]*)"', text))
    m = rng.choice(ms)
    return text[:m.start(1)] + '-' + m.group(1) + text[m.end(1):], 'negative mass'


def truncate(text, rng):
    k = rng.randrange(len(text))
    return text[:k], f'truncated at {k}'


def swap_parent_child(text, rng):
    js = list(re.finditer(r'<parent\s+link="([^"]*)"\s*/>(\s*)<child\s+link="([^"]*)"\s*/>', text))
    if not js:
        return truncate(text, rng)
    m = rng.choice(js)
    return (text[:m.start()] + f'<parent link="{m.group(3)}"/>{m.group(2)}<child link="{m.group(1)}"/>'
            + text[m.end():], 'swapped parent and child')


def cycle(text, rng):
    """A joint's parent replaced by a link below it (or by its own child)."""
    ps = list(re.finditer(r'<parent\s+link="([^"]*)"', text))
    m = rng.choice(ps)
    links = _names(text, 'link')
    return text[:m.start(1)] + rng.choice(links) + text[m.end(1):], 'parent replaced (cycle or tree change)'


def duplicate_name(text, rng):
    tag = rng.choice(['link', 'joint'])
    names = _names(text, tag)
    if len(names) < 2:
        return truncate(text, rng)
    a, b = rng.sample(names, 2)
    return text.replace(f'<{tag} name="{a}"', f'<{tag} name="{b}"', 1), f'duplicate {tag} name {b!r}'


def delete_element(text, rng):
    ms = list(_TAG.finditer(text))
    m = rng.choice(ms)
    end = text.find('>', m.start())
    if text[end - 1] == '/':
        return text[:m.start()] + text[end + 1:], f'deleted <{m.group(1)}/>'
    close = text.find(f'</{m.group(1)}>', end)
    if close < 0:
        return truncate(text, rng)
    return text[:m.start()] + text[close + len(m.group(1)) + 3:], f'deleted <{m.group(1)}>...</{m.group(1)}>'


def garbage(text, rng):
    k = rng.randrange(len(text))
    g = rng.choice(['\x00', '<', '&', '"', '<link>', '</robot>', '\ufeff', ']]>', '<!--'])
    return text[:k] + g + text[k:], f'inserted {g!r} at {k}'


def joint_type(text, rng):
    ms = list(re.finditer(r'(<joint\s[^>]*?type=")([^"]*)"', text))
    m = rng.choice(ms)
    t = rng.choice(['floating', 'planar', 'hinge', 'fixed', 'continuous', 'prismatic', 'revolute', ''])
    return text[:m.start(2)] + t + text[m.end(2):], f'joint type {t!r}'


def zero_axis(text, rng):
    ms = list(re.finditer(r'<axis\s+xyz="([^"]*)"', text))
    if not ms:
        return bad_number(text, rng)
    m = rng.choice(ms)
    return text[:m.start(1)] + '0 0 0' + text[m.end(1):], 'zero axis'


def massless(text, rng):
    """Every mass and inertia of one link set to zero (a massless moving link, or a leaf)."""
    ms = list(re.finditer(r'<inertial>.*?</inertial>', text, re.S))
    m = rng.choice(ms)
    block = re.sub(r'(value|ixx|iyy|izz|ixy|ixz|iyz)="[^"]*"', r'\1="0"', m.group(0))
    return text[:m.start()] + block + text[m.end():], 'massless link'


def point_mass(text, rng):
    """One link's inertia set to zero, its mass kept (a point mass)."""
    ms = list(re.finditer(r'<inertia\s[^>]*?/>', text, re.S))
    m = rng.choice(ms)
    block = re.sub(r'(ixx|iyy|izz|ixy|ixz|iyz)="[^"]*"', r'\1="0"', m.group(0))
    return text[:m.start()] + block + text[m.end():], 'point mass'


def mimic(text, rng):
    """A joint made a mimic of another joint (or of itself, or of a joint that does not exist)."""
    js = [n for n in re.findall(r'<joint\s[^>]*?name="([^"]*)"[^>]*?type="(?:revolute|continuous|prismatic)"', text)]
    if len(js) < 1:
        return truncate(text, rng)
    a = rng.choice(js)
    b = rng.choice(js + ['ghost'])
    mul = rng.choice(['1', '-1', '0', '2.5', 'nan'])
    k = text.find(f'name="{a}"')
    end = text.find('</joint>', k)
    return (text[:end] + f'<mimic joint="{b}" multiplier="{mul}" offset="0.1"/>' + text[end:],
            f'{a} mimics {b} x{mul}')


MUTATIONS = [delete_attribute, bad_number, negative_mass, truncate, swap_parent_child, cycle, duplicate_name,
             delete_element, garbage, joint_type, zero_axis, massless, point_mass, mimic]


def mutate(text: str, rng: random.Random, n: int | None = None):
    """``(mutated text, description)``: one to three mutations drawn with ``rng``."""
    done = []
    for _ in range(n or rng.choice([1, 1, 1, 2, 3])):
        try:
            text, what = rng.choice(MUTATIONS)(text, rng)
        except IndexError:  # nothing left to mutate that way (an earlier mutation removed it)
            text, what = garbage(text, rng) if text else ('<', 'emptied')
        done.append(what)
    return text, '; '.join(done)
