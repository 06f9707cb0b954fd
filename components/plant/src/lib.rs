//! `bowden-plant`: the simulated tendon-sheath manipulator every other part of bowden is
//! tested against (DESIGN.md §6), and the paper's dataset protocol run on it.
//!
//! - [`Plant`]: driven by cable displacement commands (eq. 5), hysteresis in cable space
//!   (capstan dead band growing with sheath curvature and tension, a generalised
//!   Prandtl–Ishlinskii memory per cable, elastic stretch, creep), joints back through the
//!   inverse cable equation, first-order settling. Seeded, deterministic, allocation-free steps.
//! - [`PlantConfig`]: `configs/plant.toml` (deny_unknown_fields, validated).
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
pub mod hysteresis;
pub mod plant;

pub use characterize::{characterize, Characterization, CharacterizeOptions, JointStats, PlotError};
pub use config::{PlantConfig, PlantConfigError};
pub use plant::{Plant, PlantError};
