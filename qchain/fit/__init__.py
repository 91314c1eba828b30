"""Fitting a model to a real arm's measured motion (issue 30): measurements from ROS 2 bags,
qchain recordings and CSV files (:mod:`qchain.fit.measurements`)."""

from .measurements import (
    MeasurementError,
    Measurements,
    MeasurementWarning,
    bag_topics,
    read_bag,
    read_csv,
    read_qchain,
)

__all__ = ["Measurements", "MeasurementError", "MeasurementWarning", "read_bag", "read_qchain", "read_csv",
           "bag_topics"]
