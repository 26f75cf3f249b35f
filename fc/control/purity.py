"""The pure style a compiler takes unchanged, checked on the code: the rules of the hot path.

A function in the pure style is a module-level function with no closure whose body has no lists,
dicts, sets, comprehensions, strings, f-strings, exceptions, lambdas, nested functions, imports or
``with``, and whose calls are of other pure functions by plain name, ``math`` functions,
``abs``/``min``/``max``, ``len`` (of a tuple), NamedTuple classes, or (in the pipeline) the flying law's own functions
through a :class:`fc.control.law.LawFunctions` argument. Such functions run under CPython and,
unchanged, under numba's ``njit`` (``tests/test_compilable.py`` compiles them and compares bits).

:func:`function_problems` checks one function against a set of known-pure ones;
:func:`law_problems` checks a law: its three functions and every function they call, followed
transitively (a plug-in's own helpers, :mod:`smcpilot.model`'s equations). ``smcpilot laws`` shows
the first problem of a law that is not in the style; such a law still flies, in CPython.
"""

from __future__ import annotations

import ast
import builtins
import inspect
import math
import textwrap
import types
from collections.abc import Callable, Iterable

from fc.control.law import Law, LawFunctions

_ALLOWED_BUILTINS = {abs, len, min, max}
_MATH = {v for v in vars(math).values() if callable(v)}
_FORBIDDEN_NODES = (
    ast.List, ast.ListComp, ast.Dict, ast.DictComp, ast.Set, ast.SetComp, ast.GeneratorExp, ast.JoinedStr,
    ast.Raise, ast.Try, ast.Assert, ast.Lambda, ast.ClassDef, ast.Global, ast.Nonlocal, ast.Yield, ast.YieldFrom,
    ast.With, ast.Await, ast.Starred, ast.Delete, ast.Import, ast.ImportFrom,
)  # fmt: skip


def law_arguments(fn: types.FunctionType) -> set[str]:
    """The parameters of ``fn`` annotated as :class:`fc.control.law.LawFunctions`."""
    return {name for name, ann in fn.__annotations__.items() if ann in (LawFunctions, "LawFunctions")}


def is_namedtuple_class(v: object) -> bool:
    return isinstance(v, type) and issubclass(v, tuple) and hasattr(v, "_fields")


def resolve(fn: types.FunctionType, name: str) -> object:
    """What a plain name in ``fn`` refers to: its module's global, or a builtin."""
    if name in fn.__globals__:
        return fn.__globals__[name]
    return getattr(builtins, name, None)


def _python_function(v: object) -> types.FunctionType | None:
    """A plain Python function, or the one a compiled dispatcher wraps (numba's ``py_func``)."""
    if isinstance(v, types.FunctionType):
        return v
    inner = getattr(v, "py_func", None)
    return inner if isinstance(inner, types.FunctionType) else None


#: the transitive form's answers per function (its source does not change in a process).
_TRANSITIVE: dict[types.FunctionType, tuple[list[str], list[types.FunctionType]]] = {}


def function_problems(fn: Callable, pure: Iterable[Callable] = (), *, called: list[types.FunctionType] | None = None) -> list[str]:
    """What in ``fn`` breaks the rules (empty: none). Calls must go to ``pure`` functions; with
    ``called`` given, calls of other Python functions are allowed and collected there instead
    (for a transitive check)."""
    pure = tuple(pure)
    f = _python_function(fn)
    if called is not None and not pure and f is not None:
        known = _TRANSITIVE.get(f)
        if known is None:
            found: list[types.FunctionType] = []
            known = _TRANSITIVE[f] = (_function_problems(fn, (), called=found), found)
        called.extend(known[1])
        return list(known[0])
    return _function_problems(fn, pure, called=called)


def _function_problems(fn: Callable, pure: Iterable[Callable] = (), *, called: list[types.FunctionType] | None = None) -> list[str]:
    f = _python_function(fn)
    name = getattr(fn, "__name__", repr(fn))
    if f is None:
        return [f"{name}: not a Python function"]
    if f.__qualname__ != f.__name__:
        return [f"{name}: not a module-level function ({f.__qualname__})"]
    if f.__closure__ is not None or f.__code__.co_freevars:
        return [f"{name}: a closure (captures {', '.join(f.__code__.co_freevars)})"]
    try:
        tree = ast.parse(textwrap.dedent(inspect.getsource(f)))
    except (OSError, TypeError, SyntaxError) as exc:
        return [f"{name}: source not readable ({exc})"]
    root = tree.body[0]
    if not isinstance(root, ast.FunctionDef):
        return [f"{name}: not a def"]
    body = root.body
    if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
        body = body[1:]  # the docstring
    pure_set = set(pure)
    problems = []
    for node in (n for stmt in body for n in ast.walk(stmt)):
        where = f"{name} line {getattr(node, 'lineno', '?')}"
        if isinstance(node, _FORBIDDEN_NODES) or isinstance(node, ast.FunctionDef):
            problems.append(f"{where}: {type(node).__name__}")
        elif isinstance(node, ast.Constant) and isinstance(node.value, (str, bytes)):
            problems.append(f"{where}: string constant {node.value!r}")
        elif isinstance(node, ast.Call):
            c = node.func
            if isinstance(c, ast.Attribute) and isinstance(c.value, ast.Name) and resolve(f, c.value.id) is math:
                continue  # math.isfinite(...)
            if (isinstance(c, ast.Attribute) and isinstance(c.value, ast.Name) and c.value.id in law_arguments(f)
                    and c.attr in LawFunctions._fields and not node.keywords):  # fmt: skip
                continue  # law.step(...): the law's own pure functions, passed in as a LawFunctions
            if not isinstance(c, ast.Name):
                problems.append(f"{where}: call of {ast.unparse(c)} (only plain names and math functions)")
                continue
            if node.keywords:
                problems.append(f"{where}: keyword arguments in a call of {c.id}")
            target = resolve(f, c.id)
            if target in pure_set or target in _ALLOWED_BUILTINS or target in _MATH or is_namedtuple_class(target):
                continue
            inner = _python_function(target)
            if called is not None and inner is not None:
                called.append(inner)
                continue
            problems.append(f"{where}: calls {c.id} = {target!r}, not a pure function")
        elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Load):
            v = resolve(f, node.id)
            if node.id not in f.__code__.co_varnames and v is not None and isinstance(v, (list, dict, set)):
                problems.append(f"{where}: reads the mutable global {node.id}")
    return problems


def law_problems(law: Law) -> list[str]:
    """What keeps ``law`` from the pure style: its functions and all they call, transitively."""
    return pure_closure((law.initial_state, law.step, law.anti_windup))[1]


def pure_closure(functions: Iterable[Callable]) -> tuple[tuple[types.FunctionType, ...], list[str]]:
    """``functions`` and every Python function they call, followed transitively (what a compiler
    must compile together), and what breaks the rules on the way (empty: all pure)."""
    todo: list[types.FunctionType] = []
    problems: list[str] = []
    for fn in functions:
        f = _python_function(fn)
        if f is None:
            problems.append(f"{getattr(fn, '__name__', repr(fn))}: not a Python function")
        else:
            todo.append(f)
    seen: dict[types.FunctionType, None] = {}
    while todo:
        f = todo.pop(0)
        if f in seen:
            continue
        seen[f] = None
        called: list[types.FunctionType] = []
        problems.extend(function_problems(f, called=called))
        todo.extend(called)
    return tuple(seen), problems
