# Type stubs of the Python module ukdyn (docs/python.md). The classes live in ukdyn._ukdyn (C++,
# pybind11) and are re-exported here.
from os import PathLike
from typing import Any, Callable, Literal, Optional, Sequence, Union

import numpy as np
import numpy.typing as npt

__version__: str

Expr = Union[str, float, int]
"""An expression in the syntax of docs/definitions.md (velocities are <name>_dot, time is t), or
a number."""
ArrayLike = npt.ArrayLike
FloatArray = npt.NDArray[np.float64]
Callback = Callable[[float, FloatArray, FloatArray], ArrayLike]
"""f(t, q, qd) -> n numbers: a controller's tau or an applied force's Q_a."""

class Error(Exception):
    """An error from ukdyn (its message as ukdyn prints it, FILE:LINE:COLUMN where known)."""

class ScenarioError(Error):
    """A bad scenario file: "FILE:LINE:COLUMN: key 'KEY': message"."""

class DefinitionError(Error):
    """A definition that cannot be derived (a coordinate in no body, a velocity in Phi, ...)."""

class Subsystem:
    @property
    def name(self) -> str: ...
    @property
    def dof(self) -> int: ...
    @property
    def coordinate_names(self) -> list[str]: ...

class Constraint:
    @property
    def rows(self) -> int: ...
    @property
    def row_names(self) -> list[str]: ...

class AppliedForce:
    @property
    def name(self) -> str: ...

class SubsystemDef:
    def __init__(self, name: str, coordinates: Sequence[str]) -> None: ...
    def parameter(self, name: str, value: Expr) -> None: ...
    def let(self, name: str, value: Expr) -> None: ...
    @property
    def parameters(self) -> list[str]: ...
    @property
    def name(self) -> str: ...
    @property
    def coordinates(self) -> list[str]: ...
    def add_body(
        self,
        name: str,
        mass: Expr,
        com: Sequence[Expr],
        angular_velocity: Optional[Sequence[Expr]] = None,
        rotation: Optional[Sequence[Expr]] = None,
        inertia: Union[Expr, Sequence[Expr], None] = None,
        inertia_frame: Literal["body", "world"] = "body",
    ) -> None: ...
    gravity: Sequence[Expr]
    extra_potential: Expr

class ConstraintDef:
    def __init__(
        self,
        name: str,
        kind: Literal["holonomic", "nonholonomic"],
        system_coordinates: Sequence[str],
    ) -> None: ...
    def parameter(self, name: str, value: Expr) -> None: ...
    def let(self, name: str, value: Expr) -> None: ...
    @property
    def parameters(self) -> list[str]: ...
    @property
    def name(self) -> str: ...
    def add_row(self, name: str, expression: Expr) -> None: ...

class ForceDef:
    def __init__(self, system_coordinates: Sequence[str], name: str = "forces") -> None: ...
    def parameter(self, name: str, value: Expr) -> None: ...
    def let(self, name: str, value: Expr) -> None: ...
    @property
    def parameters(self) -> list[str]: ...
    def add_generalized(self, coordinate: str, value: Expr) -> None: ...
    def add_spring_damper(
        self,
        element: str,
        a: Sequence[Expr],
        b: Sequence[Expr],
        stiffness: Expr = 0,
        damping: Expr = 0,
        rest_length: Expr = 0,
    ) -> None: ...
    def add_joint_friction(
        self,
        element: str,
        coordinate: str,
        viscous: Expr,
        coulomb: Expr = 0,
        velocity_scale: Expr = 1e-3,
    ) -> None: ...
    def add_torque(self, element: str, coordinate: str, value: Expr) -> None: ...

def make_subsystem(definition: SubsystemDef) -> Subsystem: ...
def make_constraint(definition: ConstraintDef) -> Constraint: ...
def make_applied_force(definition: ForceDef) -> AppliedForce: ...

class System:
    def __init__(self) -> None: ...
    def add_subsystem(self, subsystem: Subsystem) -> int: ...
    def add_constraint(self, constraint: Constraint) -> int: ...
    def add_applied_force(self, force: AppliedForce) -> None: ...
    @property
    def dof(self) -> int: ...
    @property
    def rows(self) -> int: ...
    @property
    def coordinate_names(self) -> list[str]: ...
    @property
    def constraint_row_names(self) -> list[str]: ...

class ForwardResult:
    M: FloatArray
    C: FloatArray
    Cqd: FloatArray
    G: FloatArray
    Q: FloatArray
    A: FloatArray
    b: FloatArray
    Qc: FloatArray
    qdd: FloatArray
    rank: int
    residual: float
    sigma_min: float
    sigma_max: float
    consistent: bool
    finite: bool

class Run:
    columns: list[str]
    summary: dict[str, Any]
    warnings: list[dict[str, Any]]
    status: str
    message: str
    complete: bool
    def __getitem__(self, name: str) -> FloatArray: ...
    def __contains__(self, name: str) -> bool: ...
    def __len__(self) -> int: ...
    def keys(self) -> list[str]: ...
    @property
    def data(self) -> FloatArray: ...
    @property
    def rows(self) -> int: ...
    @property
    def steps(self) -> int: ...
    @property
    def rhs_evaluations(self) -> int: ...

class Scenario:
    @staticmethod
    def load(path: str, check_initial: bool = True) -> Scenario: ...
    @staticmethod
    def from_text(text: str, path: str = "<string>", check_initial: bool = True) -> Scenario: ...
    @staticmethod
    def from_system(
        system: System,
        q0: ArrayLike,
        qd0: Optional[ArrayLike] = None,
        tau: Optional[ArrayLike] = None,
        t0: float = 0.0,
        t_end: float = 1.0,
        sample_dt: float = 0.01,
        integrator: Literal["rk4", "dopri5", "rkf78", "bdf"] = "dopri5",
        adaptive: bool = True,
        abs_tol: float = 1e-12,
        rel_tol: float = 1e-12,
        step: float = 1e-3,
        drift: Literal["none", "baumgarte", "projection"] = "projection",
        energy_balance: bool = False,
        name: str = "python",
    ) -> Scenario: ...
    @property
    def name(self) -> str: ...
    @property
    def path(self) -> str: ...
    @property
    def description(self) -> str: ...
    @property
    def dof(self) -> int: ...
    @property
    def rows(self) -> int: ...
    @property
    def coordinate_names(self) -> list[str]: ...
    @property
    def constraint_row_names(self) -> list[str]: ...
    q0: FloatArray
    qd0: FloatArray
    tau: FloatArray
    t0: float
    t_end: float
    sample_dt: float
    energy_balance: bool
    @property
    def integrator(self) -> str: ...
    def forward(
        self,
        t: float,
        q: ArrayLike,
        qd: ArrayLike,
        tau: Optional[ArrayLike] = None,
        forces: Sequence[Callback] = (),
    ) -> ForwardResult: ...
    def simulate(
        self, controller: Optional[Callback] = None, forces: Sequence[Callback] = ()
    ) -> Run: ...
    def assemble(self) -> dict[str, Any]: ...

def load_scenario(path: Union[str, PathLike[str]], check_initial: bool = True) -> Scenario: ...
