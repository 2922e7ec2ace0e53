"""Functions of time written as text (``"pi/3 + t"``), with exact first and second derivatives.

A scene writes a prescribed joint motion as an expression of the time ``t`` (s). This module
parses it with :mod:`ast` against a whitelist — numbers, ``t``, the constants ``pi`` and ``e``,
``+ - * / **``, unary ``-``/``+``, and calls of the functions in :data:`FUNCTIONS` — and refuses
everything else (names, attributes, subscripts, comparisons, keyword arguments, lambdas, ...):
nothing is ever passed to ``eval``.

The parsed expression is evaluated in second-order forward mode: every node carries the truncated
Taylor jet ``(f, f', f'')`` of its value in t, and each whitelisted operation propagates all three
by the chain rule,

    (a b)'' = a'' b + 2 a' b' + a b'',      (a / b) = c:  c' = (a' − c b') / b,
                                                          c'' = (a'' − 2 c' b' − c b'') / b,
    g(a)'   = g'(a) a',                     g(a)''  = g''(a) a'² + g'(a) a'',

so q, q̇ and q̈ are exact to rounding (no finite differences, no step size). ``x ** n`` with a
constant n uses n x^(n−1) and n (n−1) x^(n−2); a t-dependent exponent goes through
``exp(n log x)``. Values may be numpy arrays of t (element-wise).
"""
from __future__ import annotations

import ast
import math

import numpy as np

__all__ = ['ExpressionError', 'TimeFunction', 'parse_time_function', 'FUNCTIONS', 'CONSTANTS']


class ExpressionError(ValueError):
    """Text that is not a whitelisted expression of t; the message says what is allowed."""


#: named constants an expression may use
CONSTANTS = {'pi': math.pi, 'e': math.e}


def _jet_unary(g, g1, g2):
    """A jet function from g, g' and g'' (numpy ufuncs of the value)."""
    def f(x):
        v, d1, d2 = x
        gp = g1(v)
        return g(v), gp * d1, g2(v) * d1 * d1 + gp * d2
    return f


def _sec2(v):
    return 1.0 / np.cos(v) ** 2


#: function name -> jet map (value, first, second derivative of the function itself)
FUNCTIONS = {
    'sin': _jet_unary(np.sin, np.cos, lambda v: -np.sin(v)),
    'cos': _jet_unary(np.cos, lambda v: -np.sin(v), lambda v: -np.cos(v)),
    'tan': _jet_unary(np.tan, _sec2, lambda v: 2.0 * _sec2(v) * np.tan(v)),
    'exp': _jet_unary(np.exp, np.exp, np.exp),
    'log': _jet_unary(np.log, lambda v: 1.0 / v, lambda v: -1.0 / v ** 2),
    'sqrt': _jet_unary(np.sqrt, lambda v: 0.5 / np.sqrt(v), lambda v: -0.25 / v ** 1.5),
    'sinh': _jet_unary(np.sinh, np.cosh, np.sinh),
    'cosh': _jet_unary(np.cosh, np.sinh, np.cosh),
    'tanh': _jet_unary(np.tanh, lambda v: 1.0 - np.tanh(v) ** 2,
                       lambda v: -2.0 * np.tanh(v) * (1.0 - np.tanh(v) ** 2)),
    'arctan': _jet_unary(np.arctan, lambda v: 1.0 / (1.0 + v * v), lambda v: -2.0 * v / (1.0 + v * v) ** 2),
    'arcsin': _jet_unary(np.arcsin, lambda v: 1.0 / np.sqrt(1.0 - v * v), lambda v: v / (1.0 - v * v) ** 1.5),
    'arccos': _jet_unary(np.arccos, lambda v: -1.0 / np.sqrt(1.0 - v * v), lambda v: -v / (1.0 - v * v) ** 1.5),
}


def _add(a, b):
    return a[0] + b[0], a[1] + b[1], a[2] + b[2]


def _sub(a, b):
    return a[0] - b[0], a[1] - b[1], a[2] - b[2]


def _mul(a, b):
    return a[0] * b[0], a[1] * b[0] + a[0] * b[1], a[2] * b[0] + 2.0 * a[1] * b[1] + a[0] * b[2]


def _div(a, b):
    c = a[0] / b[0]
    c1 = (a[1] - c * b[1]) / b[0]
    return c, c1, (a[2] - 2.0 * c1 * b[1] - c * b[2]) / b[0]


def _pow(a, b, b_const):
    if b_const:  # x ** n, n constant (a float: constants are carried as plain floats)
        n = float(b[0])
        v = a[0]
        g1 = n * v ** (n - 1.0) if n != 0.0 else 0.0
        g2 = n * (n - 1.0) * v ** (n - 2.0) if n not in (0.0, 1.0) else 0.0
        return v ** n, g1 * a[1], g2 * a[1] * a[1] + g1 * a[2]
    return FUNCTIONS['exp'](_mul(b, FUNCTIONS['log'](a)))


_BINOPS = {ast.Add: ('+', _add), ast.Sub: ('-', _sub), ast.Mult: ('*', _mul), ast.Div: ('/', _div)}
_ALLOWED = ('numbers, t, ' + ', '.join(CONSTANTS) + ', + - * / ** and the functions ' + ', '.join(FUNCTIONS))


def _compile(node, text):
    """``(fn(t_jet) -> jet, is_constant)`` for an AST node, or ExpressionError."""
    if isinstance(node, ast.Constant):
        if isinstance(node.value, bool) or not isinstance(node.value, (int, float)):
            raise ExpressionError(f'{text!r}: constant {node.value!r} is not a real number; allowed: {_ALLOWED}')
        c = float(node.value)
        return (lambda tj: (c, 0.0, 0.0)), True
    if isinstance(node, ast.Name):
        if node.id == 't':
            return (lambda tj: tj), False
        if node.id in CONSTANTS:
            c = CONSTANTS[node.id]
            return (lambda tj: (c, 0.0, 0.0)), True
        raise ExpressionError(f'{text!r}: unknown name {node.id!r}; allowed: {_ALLOWED}')
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
        f, const = _compile(node.operand, text)
        if isinstance(node.op, ast.UAdd):
            return f, const
        return (lambda tj: tuple(-x for x in f(tj))), const
    if isinstance(node, ast.BinOp):
        fa, ca = _compile(node.left, text)
        fb, cb = _compile(node.right, text)
        if isinstance(node.op, ast.Pow):
            return (lambda tj: _pow(fa(tj), fb(tj), cb)), ca and cb
        op = _BINOPS.get(type(node.op))
        if op is None:
            raise ExpressionError(f'{text!r}: operator {type(node.op).__name__} is not allowed; allowed: {_ALLOWED}')
        fn = op[1]
        return (lambda tj: fn(fa(tj), fb(tj))), ca and cb
    if isinstance(node, ast.Call):
        if not isinstance(node.func, ast.Name) or node.func.id not in FUNCTIONS:
            what = node.func.id if isinstance(node.func, ast.Name) else ast.dump(node.func)
            raise ExpressionError(f'{text!r}: function {what!r} is not allowed; allowed: {_ALLOWED}')
        if node.keywords or len(node.args) != 1:
            raise ExpressionError(f'{text!r}: {node.func.id}() takes exactly one positional argument')
        g = FUNCTIONS[node.func.id]
        fa, ca = _compile(node.args[0], text)
        return (lambda tj: g(fa(tj))), ca
    raise ExpressionError(f'{text!r}: {type(node).__name__} is not allowed; allowed: {_ALLOWED}')


class TimeFunction:
    """A parsed function of time: ``f(t)``, ``f.jet(t) -> (f, f', f'')``.

    text: the expression as written (kept for messages and metadata).
    """

    def __init__(self, text: str, fn, constant: bool):
        self.text = text
        self._fn = fn
        self.constant = constant

    def jet(self, t):
        """``(f(t), f'(t), f''(t))``, floats for a float t, arrays for an array t."""
        t = np.asarray(t, dtype=float)
        one = np.ones_like(t)
        v, d1, d2 = self._fn((t, one, 0.0 * one))
        if t.ndim == 0:
            return float(v), float(d1), float(d2)
        return np.broadcast_to(v, t.shape).copy(), np.broadcast_to(d1, t.shape).copy(), \
            np.broadcast_to(d2, t.shape).copy()

    def __call__(self, t):
        return self.jet(t)[0]

    def __repr__(self):
        return f'TimeFunction({self.text!r})'


def parse_time_function(text) -> TimeFunction:
    """Parse ``text`` (a str, or a number meaning a constant) into a :class:`TimeFunction`.

    Raises :class:`ExpressionError` naming what is not allowed; the result is checked to be
    finite at t = 0 only by its users (a motion may legitimately start later).
    """
    if isinstance(text, bool):
        raise ExpressionError(f'expected an expression of t or a number, got {text!r}')
    if isinstance(text, (int, float)):
        text = repr(float(text))
    if not isinstance(text, str) or not text.strip():
        raise ExpressionError(f'expected an expression of t (a non-empty string), got {text!r}')
    if len(text) > 1000:
        raise ExpressionError(f'expression of {len(text)} characters; at most 1000 are accepted')
    try:
        tree = ast.parse(text.strip(), mode='eval')
    except SyntaxError as e:
        raise ExpressionError(f'{text!r}: not an expression ({e.msg}); allowed: {_ALLOWED}') from None
    fn, const = _compile(tree.body, text)
    return TimeFunction(text, fn, const)
