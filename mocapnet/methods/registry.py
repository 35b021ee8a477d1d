"""One interface for every cleaning method, and a registry that builds them from strings.

Two kinds of method, by the space they work in:

* ``"angles"``: ``clean(noisy: Motion, mask: [T, C] bool) -> [T, C]`` — ``noisy.channels`` holds the
  corrupted channels with NaN where ``mask`` is True (missing); returns cleaned channels (degrees).
* ``"points"``: ``clean(noisy: Markers) -> [T, M, 3]`` — missing samples are ``~noisy.visible`` (NaN in
  ``noisy.points``); returns every point filled, in cm, visible samples unchanged.

A method string is ``name``, ``name:key=value,key=value`` (options) or ``name=path[,path]`` (checkpoints),
e.g. ``gaussian-58ms``, ``knn:k=8``, ``ebf=run/last.ckpt``.
"""

from __future__ import annotations

import ast
import importlib
from collections.abc import Callable, Sequence
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
class MethodSpec:
    name: str
    space: str
    factory: Callable[..., Callable]
    help: str


@dataclass
class Method:
    """A built method: ``name`` as the user wrote it, its space and the ``clean`` callable."""

    name: str
    space: str
    clean: Callable
    options: dict[str, Any] = field(default_factory=dict)


_REGISTRY: dict[str, dict[str, MethodSpec]] = {}  # name -> space -> spec
# Methods defined in modules that are imported only when asked for (keeps torch out of `import mocapnet`).
_LAZY: dict[str, str] = {
    "hold": "mocapnet.methods.extrapolate",
    "extrapolate": "mocapnet.methods.extrapolate",
    "extrapolate+cm": "mocapnet.methods.extrapolate",
    "extrapolate-linear": "mocapnet.methods.extrapolate",
    "extrapolate-circular": "mocapnet.methods.extrapolate",
    "knn": "mocapnet.methods.knn",
    "pca": "mocapnet.methods.knn",
    "rigid": "mocapnet.methods.rigid",
    "auto": "mocapnet.methods.autofill",
    "ebf": "mocapnet.methods.neural",
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
        _REGISTRY.setdefault(name, {})[space] = MethodSpec(name, space, factory, help)
        return factory

    return deco


def _ensure_builtin() -> None:
    import mocapnet.methods.baselines  # noqa: F401  (registers the baselines)


def _parse_options(text: str, rest: str) -> dict[str, Any]:
    options: dict[str, Any] = {}
    for item in filter(None, rest.split(",")):
        key, eq, value = item.partition("=")
        if not eq:
            raise ValueError(f"method {text!r}: option {item!r} must be key=value")
        try:
            options[key.strip()] = ast.literal_eval(value.strip())
        except (ValueError, SyntaxError):
            options[key.strip()] = value.strip()
    return options


def parse_method(text: str) -> tuple[str, dict[str, Any]]:
    """Split ``name:k=v,...``, ``name=ckpt[,ckpt]`` or both (``name=ckpt[,ckpt]:k=v,...``) into the name and
    an options dict (checkpoints under ``"checkpoints"``)."""
    text = text.strip()
    if ":" in text and ("=" not in text or text.index(":") < text.index("=")):
        name, _, rest = text.partition(":")
        return name.strip(), _parse_options(text, rest)
    if "=" in text:
        name, _, rest = text.partition("=")
        paths, _, rest = rest.partition(":")
        options = _parse_options(text, rest)
        options["checkpoints"] = [p.strip() for p in paths.split(",") if p.strip()]
        return name.strip(), options
    return text, {}


def available() -> list[MethodSpec]:
    """Every registered method and space (imports the lazy modules that can be imported)."""
    _ensure_builtin()
    for module in sorted(set(_LAZY.values())):
        try:
            importlib.import_module(module)
        except ImportError:
            continue
    return [spec for name in sorted(_REGISTRY) for spec in _REGISTRY[name].values()]


def spaces_of(name: str) -> tuple[str, ...]:
    """The spaces (``"angles"``, ``"points"``) a method name is registered for."""
    _ensure_builtin()
    if name not in _REGISTRY and name in _LAZY:
        importlib.import_module(_LAZY[name])
    if name not in _REGISTRY:
        known = sorted(set(_REGISTRY) | set(_LAZY))
        raise KeyError(f"unknown method {name!r}; known methods: {', '.join(known)}")
    return tuple(s for s in SPACES if s in _REGISTRY[name])


def get_spec(name: str, space: str | None = None) -> MethodSpec:
    """The spec of ``name`` in ``space`` (default: angles when it has both). Raises KeyError naming the
    known methods, or ValueError when the method does not work in ``space``."""
    spaces = spaces_of(name)
    if space is None:
        space = spaces[0]
    if space not in spaces:
        raise ValueError(f"method {name!r} works on {' and '.join(spaces)}, not on {space}")
    return _REGISTRY[name][space]


def build_method(text: str, context: MethodContext | None = None, space: str | None = None) -> Method:
    """Build a method from its string (see module docstring), in ``space`` when it has several."""
    name, options = parse_method(text)
    spec = get_spec(name, space)
    try:
        clean = spec.factory(context or MethodContext(), **options)
    except TypeError as exc:
        raise ValueError(f"method {text!r}: {exc}") from exc
    return Method(text, spec.space, clean, options)
