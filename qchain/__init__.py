"""qchain: quasi-Lagrangian dynamics of soft continuum arms (Olguin-Diaz et al.).

Entry points (each imported on first use, PEP 562, so that ``import qchain`` loads no
numpy, Pinocchio or numba and changes no global state):

==============================================  =============================================
the model                                       :class:`Segment`, :class:`Chain`, :class:`Data`,
                                                :class:`LagrangianChain`, :class:`Frames`
statics                                         :func:`equilibrium`
parameter derivatives                           :class:`Parameters` (and the :class:`Chain` methods
                                                ``*_dynamics_parameter_derivatives``)
contact and loads                               :class:`Environment`, :class:`ContactLaw`,
                                                :class:`PointLoad`, :class:`HalfSpace`,
                                                :class:`Sphere`, :class:`Capsule`,
                                                :class:`Cylinder`, :class:`Box`, :class:`Motion`
                                                (:mod:`qchain.contact`)
time integration                                :func:`simulate`, :class:`Event`, :data:`METHODS`,
                                                :class:`Trajectory`, :class:`Budget`,
                                                :func:`compile_all`, :func:`sensitivities`
input schedules                                 :class:`Constant`, :class:`Step`, :class:`Ramp`,
                                                :class:`Sine`, :class:`Table`, :class:`SineMotion`
scene files                                     :class:`Scene`, :func:`load_scene`, :func:`parse_scene`
batches and sweeps                              :func:`simulate_batch`, :class:`BatchTrajectory`,
                                                :func:`sweep`, :func:`run_sweep`
recordings                                      :class:`RunLogger`, :func:`read_recording`,
                                                :func:`replay`, :func:`recover`, :func:`export_ros2`
calibration                                     :mod:`qchain.fit` (``qchain.fit.fit``)
errors                                          :class:`QchainError` and its kinds
==============================================  =============================================

The package reads top-down (``docs/architecture.md``): ``checks`` and ``errors`` at the
bottom, then ``model`` (one segment's math), ``algorithms`` (the recursive passes and their
derivatives), ``contact`` (obstacles, the contact law, loads), ``arm`` (:class:`Chain` and its methods), ``sim`` (integration and the compiled
engine), ``scene`` and ``recording``, ``batch``, ``fit``, and ``cli`` on top. ``qchain.segment``,
``qchain.chain``, ``qchain.recursive`` and ``qchain.logging`` are public faces over them.
"""

import importlib
import sys

__version__ = "0.1.0"

#: Each public name and the module that defines it, relative to this package.
_EXPORTS = {
    "Segment": "model.segment", "Tendon": "model.tendon",
    "Chain": "arm.chain", "Frames": "arm.kinematics", "Data": "arm.data", "LagrangianChain": "arm.lagrangian",
    "equilibrium": "arm.statics", "EquilibriumResult": "arm.statics", "Parameters": "arm.parameter_derivatives",
    "Environment": "contact.environment", "ContactLaw": "contact.environment", "PointLoad": "contact.environment",
    "HalfSpace": "contact.shapes", "Sphere": "contact.shapes", "Capsule": "contact.shapes",
    "Cylinder": "contact.shapes", "Box": "contact.shapes", "Motion": "contact.shapes",
    "simulate": "sim.simulation", "Event": "sim.simulation", "METHODS": "sim.simulation",
    "Trajectory": "sim.trajectory", "Budget": "sim.budget", "BudgetError": "errors",
    "compile_all": "sim.engine.compile", "sensitivities": "sim.sensitivity",
    "Constant": "sim.inputs", "Step": "sim.inputs", "Ramp": "sim.inputs", "Sine": "sim.inputs", "Table": "sim.inputs",
    "SineMotion": "sim.inputs",
    "Scene": "scene.scene", "SceneError": "errors", "load_scene": "scene.reading", "parse_scene": "scene.reading",
    "simulate_batch": "batch.rollouts", "BatchTrajectory": "batch.rollouts", "RolloutError": "errors",
    "sweep": "batch.sweeps", "run_sweep": "batch.sweeps", "SweepResult": "batch.sweeps",
    "RunLogger": "recording.logger", "read_recording": "recording.reader", "replay": "recording.replay",
    "recover": "recording.replay", "export_ros2": "recording.ros2",
    "QchainError": "errors", "DomainError": "errors", "SingularConfigurationError": "errors",
    "NonFiniteError": "errors", "PythonBackendWarning": "errors",
}

__all__ = [*_EXPORTS, "__version__"]


def lazy_exports(package: str, exports: dict[str, str]):
    """``(__getattr__, __dir__)`` for ``package`` (PEP 562): each name of ``exports`` is
    imported from its module (relative to ``package``) on first use, then kept. Only the
    names listed: no other attribute triggers an import."""

    def getattr_(name: str):
        if name not in exports:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(f"{package}.{exports[name]}"), name)
        setattr(sys.modules[package], name, value)
        return value

    def dir_():
        return sorted(set(vars(sys.modules[package])) | set(exports))

    return getattr_, dir_


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
