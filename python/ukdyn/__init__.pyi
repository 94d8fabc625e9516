# Type stubs of the Python module ukdyn (docs/python.md). The classes live in ukdyn._ukdyn (C++,
# pybind11) and are re-exported here.
from os import PathLike
from typing import Any, Callable, Literal, Optional, Protocol, Sequence, Union, overload

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

class ControlData:
    """What a Python control law sees besides (t, q, qd): the controller's model at the measured
    state (forward() with the model's own tau, every row), as ukdyn's built-in laws see it
    (docs/control.md). Copies. n coordinates, m rows of the model (physical and servo), k
    actuators."""
    @property
    def t(self) -> float: ...
    @property
    def M(self) -> FloatArray:
        """the model's mass matrix, n x n"""
    @property
    def Q(self) -> FloatArray:
        """tau + Q_a - C qd - G of the model, n"""
    @property
    def A(self) -> FloatArray:
        """constraint matrix of all the model's rows, m x n"""
    @property
    def b(self) -> FloatArray:
        """constraint right-hand side, m (A qdd = b)"""
    @property
    def Qc(self) -> FloatArray:
        """the model's U-K constraint force (paper Eq. (4)), n"""
    @property
    def qdd(self) -> FloatArray:
        """the model's accelerations M^-1 (Q + Qc), n"""
    @property
    def phi(self) -> FloatArray:
        """position residuals Phi(q, t) of every row, m"""
    @property
    def phid(self) -> FloatArray:
        """velocity residuals dPhi/dt of every row, m"""
    @property
    def servo(self) -> npt.NDArray[np.bool_]:
        """m booleans: the servo rows (role: servo)"""
    @property
    def B(self) -> FloatArray:
        """the actuators' input map tau = B u, n x k"""
    @property
    def limit(self) -> FloatArray:
        """|u_j| allowed, k (inf: none); u is clipped at it"""
    @property
    def tau(self) -> FloatArray:
        """the model's constant forces.tau, n"""
    @property
    def rank(self) -> int:
        """numerical rank of the model's A M^-1/2"""

class ControlLawObject(Protocol):
    def control(
        self, t: float, q: FloatArray, qd: FloatArray, data: ControlData
    ) -> ArrayLike: ...

ControlLaw = Union[
    Callable[[float, FloatArray, FloatArray, ControlData], ArrayLike], ControlLawObject
]
"""law(t, q, qd, data) -> u (one number per actuator), or an object with a method
control(t, q, qd, data): replaces the built-in law of a scenario's control: section. Called at
every right-hand-side evaluation and at every sample (a continuous-time controller), with the GIL
taken for the call only."""

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

class Data:
    """Reusable buffers of forward dynamics for one scenario (Scenario.make_data()); the arrays are
    views of the C++ buffers, refreshed in place by forward(q, qd, t=..., out=data)."""
    M: FloatArray
    Cqd: FloatArray
    G: FloatArray
    Q: FloatArray
    A: FloatArray
    b: FloatArray
    Qc: FloatArray
    qdd: FloatArray
    t: float
    @property
    def rank(self) -> int: ...
    @property
    def residual(self) -> float: ...
    @property
    def consistent(self) -> bool: ...
    @property
    def sigma_min(self) -> float: ...

class Linearization:
    qdd: FloatArray
    Qc: FloatArray
    dqdd_dq: FloatArray
    dqdd_dqd: FloatArray
    dqdd_dtau: FloatArray
    dQc_dq: FloatArray
    dQc_dqd: FloatArray
    dQc_dtau: FloatArray
    dqdd_dt: Optional[FloatArray]
    dQc_dt: Optional[FloatArray]
    dmu_dt: Optional[FloatArray]
    time_message: str
    F: FloatArray
    G: FloatArray
    rank: int
    kept_rows: list[str]
    kkt_agreement: float
    trusted: bool
    message: str
    dt: Optional[float]
    Fd: Optional[FloatArray]
    Gd: Optional[FloatArray]
    N: Optional[FloatArray]
    T: Optional[FloatArray]
    D: Optional[FloatArray]
    F_min: Optional[FloatArray]
    G_min: Optional[FloatArray]
    Fd_min: Optional[FloatArray]
    Gd_min: Optional[FloatArray]
    at_rest: Optional[bool]
    rheonomic: Optional[bool]
    minimal_note: str

class StructuredDerivatives:
    @property
    def structured(self) -> bool: ...
    qdd: FloatArray
    XL: Optional[FloatArray]
    blocks: list[dict[str, Any]]
    @property
    def load_start(self) -> int: ...
    @property
    def load_size(self) -> int: ...
    @property
    def trusted(self) -> bool: ...
    @property
    def message(self) -> str: ...
    def dqdd_dx_times(self, V: ArrayLike) -> FloatArray:
        """[dqdd/dq dqdd/dqd] V for V of shape (2n,) or (2n, k), O(N k) when structured"""
    def dense(self) -> tuple[FloatArray, FloatArray]:
        """(dqdd_dq, dqdd_dqd), n x n each, expanded"""

class Optimized:
    t: FloatArray
    knot: list[bool]
    q: FloatArray
    qd: FloatArray
    qdd: FloatArray
    u: FloatArray
    Qc: FloatArray
    mu: FloatArray
    coordinates: list[str]
    actuators: list[str]
    rows: list[str]
    cost: float
    duration: float
    status: str
    converged: bool
    trusted: bool
    message: str
    iterations: int
    dual_infeasibility: float
    max_defect: float
    max_position_residual: float
    max_velocity_residual: float
    max_correction_ratio: float
    max_waypoint_residual: float
    internal_wrench: FloatArray
    replay_max_q_deviation: Optional[float]

def ipopt_available() -> bool: ...
def optimize(
    path: Union[str, PathLike[str]], out: Optional[Union[str, PathLike[str]]] = None
) -> Optimized: ...
def size(
    path: Union[str, PathLike[str]], out: Optional[Union[str, PathLike[str]]] = None
) -> dict[str, Any]: ...

class Run:
    columns: list[str]
    summary: dict[str, Any]
    warnings: list[dict[str, Any]]
    status: str
    message: str
    complete: bool
    assembly: Optional[dict[str, Any]]
    def __getitem__(self, name: str) -> FloatArray: ...
    def __contains__(self, name: str) -> bool: ...
    def __len__(self) -> int: ...
    def keys(self) -> list[str]: ...
    @property
    def data(self) -> FloatArray: ...
    @property
    def rows(self) -> int: ...
    def wrench(self, constraint: str, form: str = "world") -> FloatArray: ...
    def pose(self, constraint: str) -> FloatArray: ...
    @property
    def velocity_level_rows(self) -> list[str]: ...
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
        integrator: Literal["rk4", "dopri5", "rkf78", "bdf", "esdirk"] = "dopri5",
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
    abs_tol: float
    rel_tol: float
    initial_tolerance: float
    energy_balance: bool
    @property
    def integrator(self) -> str: ...
    @overload
    def forward(
        self,
        t: float,
        q: ArrayLike,
        qd: ArrayLike,
        tau: Optional[ArrayLike] = None,
        forces: Sequence[Callback] = (),
    ) -> ForwardResult: ...
    @overload
    def forward(
        self,
        q: ArrayLike,
        qd: ArrayLike,
        out: Data,
        t: float = 0.0,
        tau: Optional[ArrayLike] = None,
    ) -> Data:
        """into out's buffers: no allocation; returns out"""
    def make_data(self) -> Data: ...
    def forward_qdd(
        self,
        q: ArrayLike,
        qd: ArrayLike,
        t: Union[float, ArrayLike] = 0.0,
        tau: Optional[ArrayLike] = None,
        out: Optional[FloatArray] = None,
        data: Optional[Data] = None,
    ) -> FloatArray:
        """qdd of one state (n,) or of each row of (k, n) arrays"""
    def forward_batch(
        self,
        q: ArrayLike,
        qd: ArrayLike,
        *,
        t: Union[float, ArrayLike] = 0.0,
        tau: Optional[ArrayLike] = None,
    ) -> dict[str, Any]:
        """qdd, Qc (k x n), rank, residual, consistent (k) of each row"""
    @property
    def frame_names(self) -> list[str]:
        """the link frames of tree subsystems, '<subsystem>.<link>'"""
    def frame(
        self, name: str, q: ArrayLike, qd: Optional[ArrayLike] = None
    ) -> dict[str, FloatArray]:
        """p, R, v, omega, Jp, Jw of a link frame in the world frame"""
    def points(self, q: ArrayLike) -> dict[str, FloatArray]:
        """world positions of the named points at q (as the replay page draws them)"""
    def energies(self, q: ArrayLike, qd: ArrayLike, *, t: float = 0.0) -> dict[str, float]:
        """T, V, E"""
    def constraints(self, q: ArrayLike, qd: ArrayLike, *, t: float = 0.0) -> dict[str, Any]:
        """phi, phid, A, b, rank, rank_uk, free_dof, rows"""
    def inverse_dynamics(
        self, q: ArrayLike, qd: ArrayLike, qdd: ArrayLike, *, t: float = 0.0, tol: float = 1e-9
    ) -> dict[str, Any]:
        """least-norm tau and Qc for qdd on the manifold: tau, Qc, lambda, acc_residual,
        residual"""
    @property
    def actuator_names(self) -> list[str]:
        """the actuators (`actuators:`), in the order of u"""
    @property
    def control_law(self) -> Optional[str]:
        """the built-in law of the control: section (feedforward, stabilized, robust), or None"""
    def simulate(
        self,
        controller: Optional[Callback] = None,
        forces: Sequence[Callback] = (),
        *,
        control_law: Optional[ControlLaw] = None,
        q0: Optional[ArrayLike] = None,
        qd0: Optional[ArrayLike] = None,
        t0: Optional[float] = None,
        t_end: Optional[float] = None,
        assemble: bool = False,
    ) -> Run:
        """Runs the scenario as `ukdyn simulate` does, in memory. With a control: section, the
        closed loop (plant integrated, columns u_*, e_*, ed_*, Qp_*, Qs_*, summary["control"]);
        control_law replaces its built-in law. controller / forces: scenarios without control:."""
    def assemble(self) -> dict[str, Any]: ...
    def linearize(
        self,
        t: float,
        q: ArrayLike,
        qd: ArrayLike,
        tau: Optional[ArrayLike] = None,
        *,
        minimal: bool = False,
        dt: Optional[float] = None,
        forces: Sequence[Callback] = (),
    ) -> Linearization:
        """Exact derivatives of qdd and Qc at (t, q, qd, tau); check .trusted; minimal: the model
        in minimal coordinates on the constraint manifold; dt: the zero-order-hold discrete model;
        forces: Python applied forces with methods dQ_dq, dQ_dqd (and dQ_dt for dqdd_dt)
        (docs/derivatives.md, docs/python.md)"""
    def linearize_structured(
        self,
        t: float,
        q: ArrayLike,
        qd: ArrayLike,
        tau: Optional[ArrayLike] = None,
    ) -> StructuredDerivatives:
        """dqdd/d(q, qd) as the load's response XL and per-robot blocks (O(N) storage for N
        robots on one load) where the block-arrow KKT solve runs, else the dense matrices
        (docs/derivatives.md, "Cost")"""
    def parameter_derivatives(
        self,
        parameters: Sequence[str],
        t: float,
        q: ArrayLike,
        qd: ArrayLike,
        tau: Optional[ArrayLike] = None,
    ) -> dict[str, Any]:
        """dqdd_dp, dQc_dp (n x P) at (t, q, qd, tau) for numbers of the scenario file (a
        parameters: key or a path), dq0_dp, dqd0_dp, paths, trusted, message
        (docs/derivatives.md, "Sensitivities to parameters")"""
    def sensitivities(self, parameters: Sequence[str]) -> dict[str, Any]:
        """dq/dp, dqd/dp (P x T x n) of the scenario's run by the variational equations, with t,
        q, qd, steps, rhs_evaluations, trusted, message, warnings (a control scenario: the
        plant's closed loop; a gain such as 'control.kappa' is a parameter; law_derivative says
        how the law's d tau/dx was taken, exact or by directional differences)"""
    def closed_loop_linearize(
        self,
        t: Optional[float] = None,
        q: Optional[ArrayLike] = None,
        qd: Optional[ArrayLike] = None,
    ) -> dict[str, Any]:
        """A control scenario's closed loop at (t, q, qd), default its start: tau, u, dtau_dq,
        dtau_dqd, dtau_dt, dtau_method, dtau_dt_method, F, N, F_min, kinks, trusted, message"""

def load_scenario(path: Union[str, PathLike[str]], check_initial: bool = True) -> Scenario: ...
