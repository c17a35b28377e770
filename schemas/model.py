"""The physics of the MuJoCo model of detected cables (``to_mjcf``, ``POST /v1/model``).

Every quantity is per metre of cable, so it does not depend on the segment length the
chains were detected with; the model divides it among its segments. Left out (None), a
stiffness or mass follows from the chain's measured radius ``r`` (``radius_m``) and a
typical PVC-jacketed stranded cable: density :data:`DEFAULT_DENSITY`, effective Young's
modulus :data:`DEFAULT_YOUNG_MODULUS` and Poisson's ratio :data:`DEFAULT_POISSON_RATIO`.
"""

from __future__ import annotations

import math

from pydantic import BaseModel, ConfigDict, Field

DEFAULT_DENSITY = 1500.0
"""kg/m^3: copper strands in a PVC jacket, averaged over the cross-section."""
DEFAULT_YOUNG_MODULUS = 10e6
"""Pa: the effective bending modulus of a flexible cable (its jacket and loose strands)."""
DEFAULT_POISSON_RATIO = 0.45
"""Of the jacket: the shear modulus is ``E / (2 (1 + nu))``."""
DEFAULT_DAMPING_TIME = 0.01
"""s: damping is this many seconds times the larger stiffness (at least five timesteps)."""


class CablePhysics(BaseModel):
    """Stiffness, damping, mass and friction of the modelled cables, and the time step.

    Examples
    --------
    ``{}``: everything from each chain's radius. ``{"bending_stiffness": 2e-3,
    "mass_per_metre": 0.05}``: a stiffer, heavier cable (the twisting stiffness and the
    damping then follow from that bending stiffness).
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    bending_stiffness: float | None = Field(
        None,
        gt=0,
        allow_inf_nan=False,
        description="EI, N m^2: bending moment per unit curvature. Default: E pi r^4 / 4 "
        "with E = 10 MPa (3.2e-4 N m^2 for r = 3 mm).",
    )
    twisting_stiffness: float | None = Field(
        None,
        gt=0,
        allow_inf_nan=False,
        description="GJ, N m^2: twisting moment per unit twist (radians per metre). Default: "
        "EI / (1 + 0.45), a solid round section; given with no bending stiffness, the "
        "bending stiffness still follows from the radius.",
    )
    damping: float | None = Field(
        None,
        ge=0,
        allow_inf_nan=False,
        description="N m^2 s: moment per unit rate of change of curvature or twist, for "
        "bending and twisting alike. Default: 0.01 s (or five timesteps, if longer) times "
        "the larger stiffness. At least the larger stiffness times the timestep, below "
        "which the model is not stable at that step.",
    )
    mass_per_metre: float | None = Field(
        None,
        gt=0,
        allow_inf_nan=False,
        description="kg/m. Default: 1500 kg/m^3 times pi r^2 (42 g/m for r = 3 mm).",
    )
    friction: float = Field(
        1.0, ge=0, allow_inf_nan=False, description="Sliding friction of the cables' surface."
    )
    timestep: float = Field(
        0.002,
        gt=0,
        le=0.01,
        allow_inf_nan=False,
        description="Simulation time step, s (MuJoCo's default). Integrator: implicitfast.",
    )
    plane_z: float | None = Field(
        None,
        allow_inf_nan=False,
        description="Height of the surface plane in the base frame, m. Default: the table "
        "plane of a plane surface; for a depth surface, the lowest point of any cable "
        "less its radius (where the lowest cable rests).",
    )

    def for_radius(self, radius: float) -> ResolvedPhysics:
        """The values for a chain of ``radius`` metres, defaults filled in."""
        area = math.pi * radius**2
        second_moment = math.pi * radius**4 / 4.0
        bending = self.bending_stiffness
        if bending is None:
            bending = DEFAULT_YOUNG_MODULUS * second_moment
        twisting = self.twisting_stiffness
        if twisting is None:
            twisting = bending / (1.0 + DEFAULT_POISSON_RATIO)
        stiffest = max(bending, twisting)
        damping = self.damping
        if damping is None:
            damping = stiffest * max(DEFAULT_DAMPING_TIME, 5.0 * self.timestep)
        mass = self.mass_per_metre
        if mass is None:
            mass = DEFAULT_DENSITY * area
        return ResolvedPhysics(
            bending_stiffness=bending,
            twisting_stiffness=twisting,
            damping=damping,
            mass_per_metre=mass,
            friction=self.friction,
            timestep=self.timestep,
        )


class ResolvedPhysics(BaseModel):
    """:class:`CablePhysics` for one chain, every value set (same units)."""

    model_config = ConfigDict(frozen=True)

    bending_stiffness: float
    twisting_stiffness: float
    damping: float
    mass_per_metre: float
    friction: float
    timestep: float
