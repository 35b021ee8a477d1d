"""One interface for every cleaning method, and a registry that builds them from strings.

Two kinds of method, by the space they work in:

* ``"angles"``: ``clean(noisy: Motion, mask: [T, C] bool) -> [T, C]`` — ``noisy.channels`` holds the
  corrupted channels with NaN where ``mask`` is True (missing); returns cleaned channels (degrees).
* ``"points"``: ``clean(noisy: Markers) -> [T, M, 3]`` — missing samples are ``~noisy.visible`` (NaN in
  ``noisy.points``); returns every point filled, in cm, visible samples unchanged.

A method string is ``name``, ``name:key=value,key=value`` (options), ``name=path[,path]`` (checkpoints) or
both, ``name=path[,path]:key=value`` — e.g. ``gaussian-58ms``, ``knn:k=8``, ``ebf=run/last.ckpt``,
``ebf=C:/runs/x.ckpt:mode=windowed``. It is parsed once, at the edge (CLI, configs), into a ``MethodSpec``;
every function taking a method accepts either.

Method modules register themselves (``register``) when imported; ``_LAZY`` names the module of each method
so that the registry imports it on first use (no import of the method modules here: they import this one).
"""

from __future__ import annotations

import ast
import importlib
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from mocapnet.motion import Markers, Motion

SPACES = ("angles", "points")


@dataclass
class MethodContext:
    """What a method may know besides its input: clean training clips of the same corpus (training folds
        for BVH corpora; every file of a C3D folder, from which a method must leave out the clip it is
        cleaning, matched by ``name``), the corpus name and the corruption being scored (for methods tuned on
    training data)."""

    train: Sequence[Motion] | Sequence[Markers] = ()
    corpus: str = ""
    corruption: str = "angular-0.5"


@dataclass(frozen=True)
class MethodEntry:
    """A registered method in one space: ``factory(context, **options) -> clean`` and a one-line help."""

    name: str
    space: str
    factory: Callable[..., Callable]
    help: str


# An option list starts at a ':' followed by `key=` (a drive letter's ':' is followed by '/' or '\').
_OPTIONS_START = re.compile(r":(?=\s*[A-Za-z_]\w*\s*=)")


@dataclass(frozen=True)
class MethodSpec:
    """A parsed method string (module docstring): ``name``, ``checkpoints`` and ``options``; ``str()`` gives
    the text as written (what tables and CSV rows show)."""

    name: str
    options: Mapping[str, Any] = field(default_factory=dict)
    checkpoints: tuple[str, ...] = ()
    text: str = ""

    @classmethod
    def parse(cls, text: str | MethodSpec) -> MethodSpec:
        """Parse ``text`` (a ``MethodSpec`` is returned as it is). Raises ValueError for an empty name or an
        option that is not ``key=value``."""
        if isinstance(text, MethodSpec):
            return text
        text = text.strip()
        cut = min((i for i in (text.find("="), text.find(":")) if i >= 0), default=len(text))
        name, sep, rest = text[:cut].strip(), text[cut : cut + 1], text[cut + 1 :]
        if not name:
            raise ValueError(f"method {text!r}: no method name")
        paths, opts = "", ""
        if sep == "=":
            found = _OPTIONS_START.search(rest)
            paths, opts = (rest[: found.start()], rest[found.end() :]) if found else (rest, "")
        elif sep == ":":
            opts = rest
        checkpoints = tuple(p.strip() for p in paths.split(",") if p.strip())
        return cls(name, _parse_options(text, opts), checkpoints, text)

    def __str__(self) -> str:
        return self.text or self.canonical()

    def canonical(self) -> str:
        """``name[=ckpt,…][:key=value,…]`` written from the parts."""
        text = self.name + ("=" + ",".join(self.checkpoints) if self.checkpoints else "")
        if self.options:
            text += ":" + ",".join(f"{k}={v}" for k, v in self.options.items())
        return text

    def with_checkpoints(self, paths: Sequence[str]) -> MethodSpec:
        """The same method with other checkpoints (e.g. from ``--model``)."""
        return MethodSpec(self.name, dict(self.options), tuple(paths))

    def with_options(self, **options: Any) -> MethodSpec:
        """The same method with ``options`` added or replaced."""
        return MethodSpec(self.name, {**self.options, **options}, self.checkpoints)

    def factory_options(self) -> dict[str, Any]:
        """Keyword arguments of the factory: the options, and the checkpoints under ``"checkpoints"``."""
        extra = {"checkpoints": list(self.checkpoints)} if self.checkpoints else {}
        return {**self.options, **extra}


@dataclass
class Method:
    """A built method: ``name`` as the user wrote it, its space and the ``clean`` callable."""

    name: str
    space: str
    clean: Callable
    options: dict[str, Any] = field(default_factory=dict)


_REGISTRY: dict[str, dict[str, MethodEntry]] = {}  # name -> space -> entry
# Methods defined in modules that are imported only when asked for (keeps torch out of `import mocapnet`); a
# name registered in several modules (e.g. knn in points and in angles) lists them all.
_LAZY: dict[str, str | tuple[str, ...]] = {
    "noisy": "mocapnet.methods.baselines",
    "gaussian-58ms": "mocapnet.methods.baselines",
    "gaussian-125ms": "mocapnet.methods.baselines",
    "gaussian-tuned": "mocapnet.methods.baselines",
    "lerp+gaussian-58ms": "mocapnet.methods.baselines",
    "gaussian-58ms+check": "mocapnet.methods.baselines",
    "gaussian-cv": "mocapnet.methods.baselines",
    "lerp": "mocapnet.methods.baselines",
    "spline": "mocapnet.methods.baselines",
    "hold": "mocapnet.methods.extrapolate",
    "extrapolate": "mocapnet.methods.extrapolate",
    "extrapolate+cm": "mocapnet.methods.extrapolate",
    "extrapolate-linear": "mocapnet.methods.extrapolate",
    "extrapolate-circular": "mocapnet.methods.extrapolate",
    "knn": ("mocapnet.methods.knn", "mocapnet.methods.knn_angles"),
    "pca": "mocapnet.methods.pca",
    "rigid": "mocapnet.methods.rigid",
    "auto": ("mocapnet.methods.autofill", "mocapnet.methods.auto_angles"),
    "ebf": "mocapnet.methods.neural",
    "ebf-paper": "mocapnet.methods.neural",
    "ebf-bias": "mocapnet.methods.neural",
    "ebf-free": "mocapnet.methods.neural",
    "ebd": "mocapnet.methods.neural",
    "ebd+ebf": "mocapnet.methods.neural",
    "bf": "mocapnet.methods.neural",
    "nn": "mocapnet.methods.neural",
}


def register(name: str, space: str, help: str) -> Callable:
    """Decorator: register ``factory(context: MethodContext, **options) -> clean`` under ``name``."""
    if space not in SPACES:
        raise ValueError(f"space must be one of {SPACES}, got {space!r}")

    def deco(factory: Callable) -> Callable:
        _REGISTRY.setdefault(name, {})[space] = MethodEntry(name, space, factory, help)
        return factory

    return deco


#: Option spellings that are not Python literals but mean one: ``knn:gated_twist=false``, ``short_chain=none``.
_WORDS = {"true": True, "false": False, "none": None, "null": None}


def _parse_options(text: str, rest: str) -> dict[str, Any]:
    """``key=value`` items (Python literals; true/false/none/null in any case; else the bare string)."""
    options: dict[str, Any] = {}
    for item in filter(None, rest.split(",")):
        key, eq, value = item.partition("=")
        if not eq:
            raise ValueError(f"method {text!r}: option {item!r} must be key=value")
        word = value.strip().lower()
        if word in _WORDS:
            options[key.strip()] = _WORDS[word]
            continue
        try:
            options[key.strip()] = ast.literal_eval(value.strip())
        except (ValueError, SyntaxError):
            options[key.strip()] = value.strip()
    return options


def parse_method(text: str | MethodSpec) -> tuple[str, dict[str, Any]]:
    """The name and factory options (checkpoints under ``"checkpoints"``) of a method string."""
    spec = MethodSpec.parse(text)
    return spec.name, spec.factory_options()


def available() -> list[MethodEntry]:
    """Every registered method and space (imports the lazy modules that can be imported)."""
    for module in sorted({m for name in _LAZY for m in _modules(name)}):
        try:
            importlib.import_module(module)
        except ImportError:
            continue
    return [spec for name in sorted(_REGISTRY) for spec in _REGISTRY[name].values()]


def _modules(name: str) -> tuple[str, ...]:
    """The modules that register ``name`` (none when it is not lazy)."""
    found = _LAZY.get(name, ())
    return (found,) if isinstance(found, str) else found


def spaces_of(name: str) -> tuple[str, ...]:
    """The spaces (``"angles"``, ``"points"``) a method name is registered for."""
    for module in _modules(name):
        importlib.import_module(module)
    if name not in _REGISTRY:
        known = sorted(set(_REGISTRY) | set(_LAZY))
        raise KeyError(f"unknown method {name!r}; known methods: {', '.join(known)}")
    return tuple(s for s in SPACES if s in _REGISTRY[name])


def get_spec(name: str, space: str | None = None) -> MethodEntry:
    """The registry entry of ``name`` in ``space`` (default: angles when it has both). Raises KeyError naming the
    known methods, or ValueError when the method does not work in ``space``."""
    spaces = spaces_of(name)
    if space is None:
        space = spaces[0]
    if space not in spaces:
        raise ValueError(f"method {name!r} works on {' and '.join(spaces)}, not on {space}")
    return _REGISTRY[name][space]


def build_method(method: str | MethodSpec, context: MethodContext | None = None, space: str | None = None) -> Method:
    """Build a method from its spec or string (see module docstring), in ``space`` when it has several."""
    spec = MethodSpec.parse(method)
    entry = get_spec(spec.name, space)
    options = spec.factory_options()
    try:
        clean = entry.factory(context or MethodContext(), **options)
    except TypeError as exc:
        raise ValueError(f"method {str(spec)!r}: {exc}") from exc
    return Method(str(spec), entry.space, clean, options)
