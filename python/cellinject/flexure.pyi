from typing import Any, Dict, Optional

def hinge(
    profile: str,
    thickness: float,
    width: float,
    radius: Optional[float] = None,
    length: Optional[float] = None,
    youngs: Optional[float] = None,
    poisson: Optional[float] = None,
    yield_strength: Optional[float] = None,
    method: str = "beam",
    plane: str = "stress",
    angle: Optional[float] = None,
) -> Dict[str, Any]:
    """`cellinject hinge --format json`: stiffnesses (N·m/rad, N/m), 6x6 compliance,
    throat stress, rotation at yield."""
