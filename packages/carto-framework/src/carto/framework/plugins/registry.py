"""Plugin discovery and the component registry.

Carto finds plugins through the ``carto`` entry-point group with pluggy. Loading is fault
tolerant: a plugin whose import fails, whose entry point names a missing object, whose hook
implementations do not match the specifications, or whose hook raises or returns something that
is not a component is recorded as a :class:`BrokenPlugin` (entry point, distribution, stage,
error) and skipped; every other plugin keeps working.

Typical use::

    from carto.framework import get_registry

    registry = get_registry()
    matcher = registry.get("matcher", "ncc")
    for info in registry.components("sensor"):
        print(info.name, info.distribution)
"""

from __future__ import annotations

import functools
import importlib
import importlib.metadata as metadata
from collections.abc import Iterable, Mapping
from typing import Any

import attrs
import pluggy

from carto.framework.component import NAME_PATTERN, Component
from carto.framework.errors import PluginError, UnknownComponentError, interrupt_behind
from carto.framework.plugins import hookspecs

_FW = "carto.framework"
ENTRY_POINT_GROUP = "carto"
"""The entry-point group in which plugin distributions declare their plugin module."""


@attrs.frozen
class Kind:
    """One kind of component: its CLI name, the hook that provides it and its base class
    (``base_path``, ``module:Class``, imported on first use of :attr:`base`: naming the
    kinds, e.g. to build the command line, loads no component module)."""

    name: str
    label: str
    hook: str
    base_path: str

    @property
    def base(self) -> type[Component]:
        module, _, name = self.base_path.partition(":")
        return getattr(importlib.import_module(module), name)  # type: ignore[no-any-return]


KINDS: dict[str, Kind] = {
    k.name: k
    for k in (
        Kind("sensor", "sensor type", "carto_sensor_types", f"{_FW}.geometry.sensor:SensorType"),
        Kind(
            "trajectory",
            "trajectory model",
            "carto_trajectory_models",
            f"{_FW}.geometry.trajectory_models:TrajectoryModel",
        ),
        Kind("adjuster", "adjuster", "carto_adjusters", f"{_FW}.adjustment.base:Adjuster"),
        Kind("matcher", "matcher", "carto_matchers", f"{_FW}.matching.base:Matcher"),
        Kind(
            "dem-generator",
            "DEM generator",
            "carto_dem_generators",
            f"{_FW}.dem_generation.base:DEMGenerator",
        ),
        Kind(
            "scene-preset",
            "scene preset",
            "carto_scene_presets",
            f"{_FW}.simulation.preset:ScenePreset",
        ),
    )
}
"""Component kinds by name, in the order ``carto plugins`` lists them."""


@attrs.frozen
class PluginInfo:
    """A plugin that loaded: entry-point name and the distribution that declared it."""

    name: str
    entry_point: str
    distribution: str
    version: str


@attrs.frozen
class BrokenPlugin:
    """A plugin that failed to load or register, and why.

    Attributes:
        name: entry-point name.
        entry_point: the entry point as declared, ``"name = module:object"``.
        distribution, version: the distribution that declared it.
        stage: where it failed: ``"import"``, ``"register"`` or ``"hook <hook name>"``.
        error: ``"ExceptionType: message"``.
    """

    name: str
    entry_point: str
    distribution: str
    version: str
    stage: str
    error: str

    def one_line(self) -> str:
        """``name (distribution version): stage failed: error`` on one line."""
        text = f"{self.name} ({self.distribution} {self.version}): {self.stage} failed: "
        return text + " ".join(self.error.split())


@attrs.frozen
class ComponentInfo:
    """A registered component with where it came from."""

    kind: str
    name: str
    description: str
    plugin: str
    distribution: str
    version: str
    component: Any = attrs.field(eq=False, repr=False)

    def as_dict(self) -> dict[str, str]:
        """The JSON form used by ``carto plugins --json``."""
        return {
            "kind": self.kind,
            "name": self.name,
            "description": self.description,
            "plugin": self.plugin,
            "distribution": self.distribution,
            "version": self.version,
        }


def _describe_error(exc: BaseException) -> str:
    """The one line of a plugin's failure; a Ctrl-C behind it (an import interrupted inside
    compiled code surfaces as another exception) is raised again: the user stopped the
    command, no plugin is broken (plugins import their components inside the hooks, so an
    interrupt lands there more often)."""
    from carto.framework.files.staging import interrupted

    if interrupted() is not None:  # the interrupt itself was lost on its way (ctypes)
        raise KeyboardInterrupt(interrupted())
    interrupt = interrupt_behind(exc)
    if interrupt is not None:
        raise interrupt
    return f"{type(exc).__name__}: {exc}"


def _entry_point_text(ep: metadata.EntryPoint) -> str:
    return f"{ep.name} = {ep.value}"


def _distribution_of(ep: metadata.EntryPoint) -> tuple[str, str]:
    dist = getattr(ep, "dist", None)
    if dist is None:
        return "unknown", "unknown"
    return str(dist.metadata["Name"] or dist.name), str(dist.version)


class Registry:
    """Components by kind and name, plugins that loaded, plugins that are broken.

    Build it with :func:`load_registry` (or use the process-wide :func:`get_registry`).
    """

    def __init__(
        self,
        components: Iterable[ComponentInfo],
        plugins: Iterable[PluginInfo],
        broken: Iterable[BrokenPlugin],
    ) -> None:
        self._by_kind: dict[str, dict[str, ComponentInfo]] = {k: {} for k in KINDS}
        for info in components:
            self._by_kind[info.kind][info.name] = info
        self.plugins: tuple[PluginInfo, ...] = tuple(plugins)
        self.broken: tuple[BrokenPlugin, ...] = tuple(broken)

    def _check_kind(self, kind: str) -> None:
        if kind not in KINDS:
            raise UnknownComponentError("component kind", kind, list(KINDS))

    def names(self, kind: str) -> list[str]:
        """Sorted names of the registered components of ``kind``."""
        self._check_kind(kind)
        return sorted(self._by_kind[kind])

    def info(self, kind: str, name: str) -> ComponentInfo:
        """The :class:`ComponentInfo` of component ``name`` of ``kind``.

        Raises:
            UnknownComponentError: no such component; the message lists the names that exist
                and says when broken plugins might have provided it.
        """
        self._check_kind(kind)
        try:
            return self._by_kind[kind][name]
        except KeyError:
            raise UnknownComponentError(
                KINDS[kind].label, name, self.names(kind), self._broken_note()
            ) from None

    def find(self, name: str, kind: str | None = None) -> list[ComponentInfo]:
        """Every component called ``name`` (of any kind, or of ``kind``).

        Raises:
            UnknownComponentError: there is none.
        """
        if kind is not None:
            return [self.info(kind, name)]
        found = [c for c in self.components() if c.name == name]
        if not found:
            known = sorted({c.name for c in self.components()})
            raise UnknownComponentError("component", name, known, self._broken_note())
        return found

    def _broken_note(self) -> str:
        if not self.broken:
            return ""
        names = ", ".join(sorted({b.name for b in self.broken}))
        return f"plugins that failed to load: {names}; see `carto plugins`"

    def get(self, kind: str, name: str) -> Any:
        """The component ``name`` of ``kind`` (e.g. ``get("matcher", "ncc")``)."""
        return self.info(kind, name).component

    def components(self, kind: str | None = None) -> list[ComponentInfo]:
        """All components, or those of one ``kind``, in kind order then by name."""
        kinds = list(KINDS) if kind is None else [kind]
        result: list[ComponentInfo] = []
        for k in kinds:
            self._check_kind(k)
            result.extend(self._by_kind[k][n] for n in sorted(self._by_kind[k]))
        return result


def _validate_component(obj: Any, kind: Kind) -> str | None:
    """Return why ``obj`` is not a valid component of ``kind``, or None if it is."""
    if not isinstance(obj, kind.base):
        return (
            f"returned {type(obj).__name__!s}, expected an instance of "
            f"{kind.base.__module__}.{kind.base.__qualname__}"
        )
    name = getattr(obj, "name", "")
    if not isinstance(name, str) or not NAME_PATTERN.match(name):
        return f"{kind.label} {type(obj).__name__} has invalid name {name!r}"
    description = getattr(obj, "description", "")
    if not isinstance(description, str) or not description.strip():
        return f"{kind.label} {name!r} has no description"
    return None


def load_registry(entry_points: Iterable[metadata.EntryPoint] | None = None) -> Registry:
    """Discover plugins and build a :class:`Registry`.

    Args:
        entry_points: the entry points to load; default: every entry point of the ``carto``
            group in the current environment.

    Never raises for a faulty plugin: failures are recorded in ``Registry.broken``.
    """
    if entry_points is None:
        entry_points = metadata.entry_points(group=ENTRY_POINT_GROUP)
    unique: dict[tuple[str, str], metadata.EntryPoint] = {}
    for ep in entry_points:
        unique.setdefault((ep.name, ep.value), ep)
    pm = pluggy.PluginManager(hookspecs.PROJECT_NAME)
    pm.add_hookspecs(hookspecs)
    broken: list[BrokenPlugin] = []
    sources: dict[str, PluginInfo] = {}
    for (name, _value), ep in sorted(unique.items()):
        why = _register(pm, name, ep, sources)
        if why is None:
            sources[name] = PluginInfo(name, _entry_point_text(ep), *_distribution_of(ep))
        else:
            stage, error = why
            broken.append(
                BrokenPlugin(ep.name, _entry_point_text(ep), *_distribution_of(ep), stage, error)
            )
    components = _components(pm, sources, broken)
    return Registry(components, list(sources.values()), broken)


def _register(
    pm: pluggy.PluginManager,
    name: str,
    ep: metadata.EntryPoint,
    sources: Mapping[str, PluginInfo],
) -> tuple[str, str] | None:
    """Import an entry point's module and register its hooks; ``(stage, error)`` when that
    fails (the name taken, the import, a hook the specifications do not have)."""
    if name in sources:
        return (
            "register",
            f"PluginError: entry-point name {name!r} is already used by "
            f"{sources[name].distribution}",
        )
    try:
        plugin = ep.load()
    except Exception as exc:  # noqa: BLE001 - any failure of a plugin import is recorded
        return "import", _describe_error(exc)
    try:
        pm.register(plugin, name=name)
        unknown = [
            caller.name for caller in (pm.get_hookcallers(plugin) or []) if not caller.has_spec()
        ]
        if unknown:
            pm.unregister(plugin)
            raise PluginError(f"implements unknown hook(s): {', '.join(sorted(unknown))}")
    except Exception as exc:  # noqa: BLE001 - pluggy validation errors and ours
        return "register", _describe_error(exc)
    return None


def _components(
    pm: pluggy.PluginManager, sources: Mapping[str, PluginInfo], broken: list[BrokenPlugin]
) -> list[ComponentInfo]:
    """Every hook's components, each kind and name once; what fails goes to ``broken``."""
    components: list[ComponentInfo] = []
    seen: dict[tuple[str, str], ComponentInfo] = {}
    for kind in KINDS.values():
        for impl in getattr(pm.hook, kind.hook).get_hookimpls():
            info = sources[impl.plugin_name]

            def record(error: str, info: PluginInfo = info, kind: Kind = kind) -> None:
                broken.append(
                    BrokenPlugin(
                        info.name,
                        info.entry_point,
                        info.distribution,
                        info.version,
                        f"hook {kind.hook}",
                        error,
                    )
                )

            try:
                result = _hook_components(impl, kind)
            except Exception as exc:  # noqa: BLE001 - a faulty hook must not stop discovery
                record(_describe_error(exc))
                continue
            for obj in result:
                key = (kind.name, obj.name)
                if key in seen:
                    other = seen[key]
                    record(
                        f"PluginError: {kind.label} {obj.name!r} is already registered by "
                        f"{other.distribution} (plugin {other.plugin})"
                    )
                    continue
                description = " ".join(obj.description.split())
                seen[key] = ComponentInfo(
                    kind.name,
                    obj.name,
                    description,
                    info.name,
                    info.distribution,
                    info.version,
                    obj,
                )
                components.append(seen[key])
    return components


def _hook_components(impl: Any, kind: Kind) -> list[Any]:
    """What one hook implementation returns, checked: a sequence of components of ``kind``
    (None: none); a :class:`PluginError` otherwise."""
    result = impl.function()
    if result is None:
        return []
    if isinstance(result, str | bytes) or not isinstance(result, Iterable):
        raise PluginError(f"returned {type(result).__name__}, expected a sequence")
    result = list(result)
    for obj in result:
        problem = _validate_component(obj, kind)
        if problem:
            raise PluginError(problem)
    return result


@functools.cache
def get_registry() -> Registry:
    """The registry of the current environment, loaded once per process."""
    return load_registry()
