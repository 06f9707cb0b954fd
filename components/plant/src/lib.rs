//! `bowden-plant`: the simulated tendon-sheath manipulator every other part of bowden is
//! tested against (docs/architecture.md §6), and the paper's dataset protocol run on it.
//!
//! - [`Plant`]: driven by cable displacement commands (eq. 5), the joint command decoded from
//!   them by the inverse cable equation; hysteresis from one of four independently formulated
//!   families, chosen by the plant file's `family` ([`FamilyKind`]); then the residual coupling
//!   matrix, per-joint gains and offsets, joint limits and jaw contact, and first-order settling.
//!   Seeded per-unit variation, deterministic, allocation-free steps, typed errors that change
//!   nothing. The families:
//!   - `capstan` (the default; [`plant`], [`hysteresis`]): cable space, rate-independent. A
//!     capstan dead band per cable growing with sheath curvature and tension, a generalised
//!     Prandtl–Ishlinskii memory per cable, elastic stretch under the joint stiffness, creep;
//!     joints back through the inverse cable equation (tendon-sheath experiments of Kaneko and of
//!     Do et al.). `configs/plant.toml`, `configs/plant-robot2.toml`.
//!   - `bouc-wen` ([`families::bouc_wen`]): joint space, rate-independent. An asymmetric Bouc–Wen
//!     lag per joint behind its decoded command (Bouc 1967; Wen 1976; Ismail, Ikhouane &
//!     Rodellar 2009; Song & Der Kiureghian 2006), widening with the bend of the proximal
//!     segments, an elastic gain loss from the cables' stretch; creep narrows the band,
//!     then adds free play and shifts the joint. `configs/plant-boucwen.toml`.
//!   - `lugre` ([`families::lugre`]): cable space, rate-dependent. Each cable an elastic spring
//!     to a massless distal slider with LuGre friction against its sheath (Canudas de Wit et al.
//!     1995), Coulomb level from the capstan relation with the sheath wrap plus the crossed
//!     bends, loaded by the joint stiffness, a free play per cable pair (Do et al.), sub-stepped
//!     at ≤ 0.25 ms. `configs/plant-lugre.toml`.
//!   - `preisach` ([`families::preisach`]): joint space, rate-dependent. A bounded friction lag
//!     per joint from a population of stick–slip contacts: a classical Preisach model (Preisach
//!     1935; Mayergoyz 1991) on the load the contacts hold, a 16 × 16 triangular grid of relay
//!     hysterons weighted by a lognormal-coercivity × split-normal-interaction density (Everett
//!     increments; Bertotti 1998), ending in gross sliding (pre-sliding hysteresis with
//!     nonlocal memory, Swevers et al. 2000): after a reversal the joint stands, then follows
//!     its command one to one at a fixed lag, with a sharp knee set by the density and
//!     wiping-out (return-point) memory; the contacts feel the command through a standard
//!     linear solid (a delayed slip: the joint creeps on toward its command for a few τ after
//!     the drive stops). `configs/plant-preisach.toml`.
//!
//!   All four are tuned into the paper's Table IV range under the dataset protocol.
//! - [`PlantConfig`]: the plant files (deny_unknown_fields, validated; the selected family's
//!   table required, the others' refused).
//! - [`characterize()`]: eq. (16) commands held 0.5 s each → Table IV figures and Fig. 9b loops.
//!
//! ```
//! use bowden_kinematics::Robot;
//! use bowden_plant::{Plant, PlantConfig};
//! let robot = Robot::paper_default();
//! let mut plant = Plant::new(&robot, &PlantConfig::paper_default(), 1);
//! let w = robot.cables().displacements_mm(&[30.0, 0.0, 20.0, -10.0, 10.0]);
//! plant.settle(&w, 0.5, 0.001).unwrap();
//! let q_phy = plant.q_phy_deg(); // lags the command by the friction dead band
//! assert!(q_phy[0] < 30.0);
//! ```

pub mod characterize;
pub mod config;
pub mod families;
pub mod hysteresis;
pub mod node;
pub mod plant;

pub use characterize::{characterize, Characterization, CharacterizeError, CharacterizeOptions, JointStats, PlotError};
pub use config::{BoucWenConfig, ConfigError, FamilyKind, LugreConfig, PlantConfig, PreisachConfig};
pub use plant::{Plant, PlantBuildError, PlantError};
