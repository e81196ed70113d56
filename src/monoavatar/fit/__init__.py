"""fit stage: pose fitting (Sec. B.3.2) and consensus shape (Sec. B.3.3)."""

from monoavatar.fit.shape import (
    CanonicalShape,
    RoundDiagnostics,
    ShapeFitError,
    ShapeSettings,
    fit_consensus_shape,
)

__all__ = [
    "CanonicalShape",
    "RoundDiagnostics",
    "ShapeFitError",
    "ShapeSettings",
    "fit_consensus_shape",
]
