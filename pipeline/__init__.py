"""usd-tween: neural motion in-betweening for UsdSkel shots."""

__version__ = "0.1.0"
