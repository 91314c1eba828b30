"""Scene files: a TOML file -> :class:`Scene` (:mod:`qchain.scene.reading`, validated as
:mod:`qchain.scene.format` declares every key) -> the smallest model that represents it
(:class:`SceneModel`, :mod:`qchain.scene.model`) -> a run. The format: ``docs/scene-format.md``.

This package imports the model and the simulation; nothing below it imports this package."""

from .. import lazy_exports

_EXPORTS = {
    "Scene": "scene", "SceneModel": "model", "SceneError": "format", "Problem": "format",
    "SegmentSpec": "parts", "BaseSpec": "parts", "SineMotion": "parts", "METHODS": "scene", "PLOTS": "format",
    "BEND_MARGIN": "model", "VACUUM_GAUGE": "scene", "load_scene": "reading", "parse_scene": "reading",
}
__all__ = list(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
