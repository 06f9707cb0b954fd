//! Tuning aid: the Table IV characterization of one plant file, quickly.
//!
//! `cargo run --release -p bowden-plant --example characterize_family -- configs/plant-lugre.toml [n_configs] [plant_seed] [dataset_seed]`
//! (the full run, `bowden plant characterize --config FILE`, uses 1802 configurations.)

use bowden_kinematics::Robot;
use bowden_plant::{characterize, CharacterizeOptions, PlantConfig};

fn main() {
    let mut args = std::env::args().skip(1);
    let path = args
        .next()
        .expect("usage: characterize_family PLANT.toml [n_configs] [plant_seed] [dataset_seed]");
    let mut next = |default: u64| args.next().map_or(default, |a| a.parse().expect("a number"));
    let (n_configs, plant_seed, dataset_seed) = (next(150), next(1), next(1));
    let config = PlantConfig::load(&path).unwrap_or_else(|e| panic!("{e}"));
    let options = CharacterizeOptions {
        n_configs: n_configs as usize,
        plant_seed,
        dataset_seed,
        ..Default::default()
    };
    let t0 = std::time::Instant::now();
    let r = characterize(&Robot::paper_default(), &config, &options, &mut |_, _| {}).unwrap_or_else(|e| panic!("{e}"));
    print!("{}", r.markdown_table());
    println!("({:.1} s)", t0.elapsed().as_secs_f64());
}
