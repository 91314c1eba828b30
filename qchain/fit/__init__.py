"""Fitting a model to a real arm's measured motion (issue 30): measurements from ROS 2 bags,
qchain recordings and CSV files (:mod:`qchain.fit.measurements`), static poses
(:mod:`qchain.fit.statics`), parameters named by scene keys (:mod:`qchain.fit.parameters`),
bounded least squares with standard errors (:mod:`qchain.fit.solve`), the fit
(:func:`fit`, :mod:`qchain.fit.fitting`)."""

from .fitting import FitReport, fit
from .measurements import (
    MeasurementError,
    Measurements,
    MeasurementWarning,
    bag_topics,
    read_bag,
    read_csv,
    read_qchain,
)
from .solve import FitResult, FitWarning, least_squares_fit
from .statics import StaticPoses

__all__ = ["fit", "FitReport", "FitResult", "FitWarning", "least_squares_fit", "StaticPoses", "Measurements", "MeasurementError", "MeasurementWarning", "read_bag", "read_qchain", "read_csv",
           "bag_topics"]
