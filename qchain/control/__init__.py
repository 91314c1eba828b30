"""Model-based control of a soft arm (issue 31): controllers as callables
``(t, q, v) -> p`` that plug into :func:`qchain.simulate`'s ``pressure=``, run at a fixed
rate, with pressures bounded to what the chambers take and their internal signals recorded
(docs/control.md).

- :class:`Controller` (:mod:`~qchain.control.base`): the base: rate, bounds, signals, ``run``;
- :func:`allocate` (:mod:`~qchain.control.allocation`): wanted force to pressures, bounded
  least squares;
- :class:`PDCompensation`, :class:`SlotineLi` (:mod:`~qchain.control.configuration`):
  configuration space;
- :class:`TipPD`, :class:`TipTracking` (:mod:`~qchain.control.task`): the tip position;
- :class:`MPC` (:mod:`~qchain.control.mpc`): model-predictive tip tracking (box-DDP on the
  exact derivatives);
- references (:mod:`~qchain.control.references`): ``q_d(t)``, ``x_d(t)``, a tip path by
  inverse kinematics.
"""

from .. import lazy_exports

_EXPORTS = {
    "Controller": "base", "Allocation": "allocation", "allocate": "allocation",
    "PDCompensation": "configuration", "SlotineLi": "configuration",
    "TipPD": "task", "TipTracking": "task", "MPC": "mpc",
    "ConfigurationReference": "references", "TipReference": "references", "TipPathReference": "references",
    "tip_inverse_kinematics": "references",
}
__all__ = list(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
