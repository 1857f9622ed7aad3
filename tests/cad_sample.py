"""A synthetic design with every CAD feature, for tests and benchmarks: the test coupon's
generator (:mod:`drawstring.fabrication.coupon`)."""

from drawstring.fabrication.coupon import (  # noqa: F401
    SIDE_BOTTOM,
    SIDE_LEFT,
    SIDE_RIGHT,
    SIDE_TOP,
    TOP_FACE,
    SampleDesign,
    cylinder_design,
    cylinder_tiles,
)
