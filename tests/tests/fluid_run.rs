//! End to end through the real binaries: `coupler run` on the small water
//! block (fluid only, lbm_proc), the summary, and the recording read back.

use std::path::PathBuf;
use std::sync::OnceLock;

use foxglove::Decode;
use integration_tests::coupler_run;

/// 0.1 s of the coarse water block (1000 steps of 100 x 25 x 40 cells).
fn water_run() -> &'static PathBuf {
    static RUN: OnceLock<PathBuf> = OnceLock::new();
    RUN.get_or_init(|| {
        coupler_run("water_block", "scenes/validation/water_block.toml", &["--set", "output.end_time=0.1"])
    })
}

fn summary() -> serde_json::Value {
    let text = std::fs::read_to_string(water_run().join("summary.json")).expect("summary.json written");
    serde_json::from_str(&text).expect("summary is JSON")
}

#[test]
fn water_block_summary() {
    let s = summary();
    assert_eq!(s["method"], "lbm");
    assert_eq!(s["status"], "completed");
    assert!((s["sim_time"].as_f64().unwrap() - 0.1).abs() < 1e-9);
    assert_eq!(s["steps"].as_u64().unwrap(), 1000);
    // Liquid mass: the mass tracking exchanges it antisymmetrically in f64;
    // what drifts is the f32 round-off of the fluid cells' densities, ~1e-8
    // per thousand steps (docs/lbm.md). 1e-6 is the bar set for the solver.
    let lbm = &s["lbm"];
    let change = lbm["mass_relative_change"].as_f64().unwrap();
    assert!(change.abs() < 1e-6, "mass change {change}");
    // 0.04 x 0.05 x 0.06 m of water = 0.12 kg, less half of the top layer of
    // cells (the initial surface lies mid-cell: 1/60 of the height), times the
    // mean hydrostatic density 1 + 3 g_L d over the 29.5 cells of depth
    // (g_L = g dt²/dx = 4.905e-5, mean depth 14.75 cells: +0.22 %).
    let m0 = lbm["mass_initial"].as_f64().unwrap();
    let expected = 0.12 * (1.0 - 0.5 / 30.0) * (1.0 + 3.0 * 4.905e-5 * 14.75);
    assert!((m0 - expected).abs() < 1e-3 * expected, "initial mass {m0} vs {expected}");
    // The front: starts at the gate (x_norm ~ 0), then runs out. In 0.1 s a
    // dam-break front cannot pass Ritter's 2 sqrt(g H0) t = 0.153 m, i.e.
    // x_norm < 0.153/0.04 = 3.8, and a real one travels at least half that far.
    let front = s["liquid_front"].as_array().unwrap();
    assert_eq!(front.len(), 11, "frames at t = 0, 0.01, ..., 0.1");
    let x0 = front[0]["x_norm"].as_f64().unwrap();
    assert!(x0.abs() < 0.1, "front at t = 0: {x0}");
    let xs: Vec<f64> = front.iter().map(|f| f["x_norm"].as_f64().unwrap()).collect();
    let last = *xs.last().unwrap();
    assert!(last > 1.0 && last < 3.8, "front at 0.1 s: {last} ({xs:?})");
    assert!(xs.windows(2).all(|w| w[1] >= w[0] - 0.05), "front recedes: {xs:?}");
    let rate = s["throughput"]["cell_updates_per_s"].as_f64().unwrap();
    assert!(rate > 0.0);
    // The stage timers under the names docs/recording.md gives, within the run's wall time.
    let stages = lbm["stage_seconds"].as_object().unwrap();
    let names: Vec<&str> = stages.keys().map(String::as_str).collect();
    assert_eq!(names, ["prepare", "stream_collide", "update_surface"]);
    let sum: f64 = stages.values().map(|v| v.as_f64().unwrap()).sum();
    assert!(sum > 0.0 && sum <= s["wall_seconds"].as_f64().unwrap(), "stage seconds {sum}");
}

#[test]
fn water_recording_reads_back() {
    let bytes = std::fs::read(water_run().join("run.mcap")).expect("run.mcap written");
    let summary = mcap::Summary::read(&bytes).unwrap().expect("finished file has a summary section");
    let topics: Vec<String> = summary.channels.values().map(|c| c.topic.clone()).collect();
    for t in ["/lbm/surface", "/lbm/slice", "/lbm/metrics", "/lbm/state", "/log"] {
        assert!(topics.iter().any(|x| x == t), "missing {t} in {topics:?}");
    }
    let (mut grids, mut surfaces, mut states) = (0, 0, 0);
    for msg in mcap::MessageStream::new(&bytes).unwrap() {
        let msg = msg.unwrap();
        match msg.channel.topic.as_str() {
            "/lbm/slice" => {
                let grid = foxglove::schemas::Grid::decode(&msg.data[..]).unwrap();
                assert_eq!(grid.column_count, 100);
                assert_eq!(grid.data.len(), 100 * 40 * 16, "fill, speed, pressure, excess for 100 x 40 cells");
                let field =
                    |cell: &[u8], f: usize| f32::from_le_bytes(cell[4 * f..4 * f + 4].try_into().unwrap()) as f64;
                // Fill levels lie in [0, 1] (walls have none).
                for cell in grid.data.chunks(16) {
                    let fill = field(cell, 0);
                    assert!((-0.01..=1.01).contains(&fill), "fill {fill}");
                }
                if grids == 0 {
                    // The block at rest: the floor cells (centre 1 mm up, under
                    // 0.06 m less half a top cell of water: 29.5 cells - 0.5 of
                    // 2 mm) carry rho g (0.059 - 0.001) = 569 Pa; the excess over
                    // the column above is zero to the f32 round-off of 1 + 3 g d.
                    // (This checks the recording's units and surface rule; that the
                    // lattice keeps rho g h at rest is lbm_proc/tests/free_surface.rs.)
                    let floor = field(&grid.data[0..16], 2);
                    assert!((floor - 1000.0 * 9.81 * 0.058).abs() < 0.01 * 569.0, "floor pressure {floor} Pa");
                    for cell in grid.data.chunks(16) {
                        assert!(field(cell, 3).abs() < 0.5, "excess at rest {} Pa", field(cell, 3));
                    }
                }
                grids += 1;
            }
            "/lbm/surface" => {
                let cloud = foxglove::schemas::PointCloud::decode(&msg.data[..]).unwrap();
                assert_eq!(cloud.point_stride, 20);
                assert!(!cloud.data.is_empty(), "a free surface exists");
                surfaces += 1;
            }
            "/lbm/state" => {
                let state = lbm_proc::run::LbmState::decode(&msg.data).unwrap();
                assert_eq!(state.fluid.dims, [100, 25, 40]);
                states += 1;
            }
            _ => {}
        }
    }
    assert_eq!((grids, surfaces), (11, 11));
    assert!(states >= 1, "a final state");
}

/// The same water block with its populations stored in f64
/// (`lbm.precision = "f64"`): the reference that measures what f32 costs.
/// Its mass is kept to f64 round-off (the f32 lattice drifts by the f32
/// round-off of 1 + 3 g d, ~1e-8 per thousand steps: a bar of 1e-11 is
/// failed by any f32 storage left on the path), its front is the f32
/// run's within the f32 round-off's effect on a 0.1 s dam break, and its
/// recorded state says its precision so that an f32 reader refuses it.
#[test]
fn water_block_in_f64_keeps_its_mass_and_matches_f32() {
    let out = coupler_run(
        "water_block_f64",
        "scenes/validation/water_block.toml",
        &["--set", "output.end_time=0.1", "--set", "lbm.precision=\"f64\""],
    );
    let text = std::fs::read_to_string(out.join("summary.json")).expect("summary.json written");
    let s: serde_json::Value = serde_json::from_str(&text).expect("summary is JSON");
    let f32_run = summary();
    assert_eq!(s["status"], "completed");
    assert_eq!(s["steps"], f32_run["steps"]);
    let change = s["lbm"]["mass_relative_change"].as_f64().unwrap();
    let change_f32 = f32_run["lbm"]["mass_relative_change"].as_f64().unwrap();
    assert!(change.abs() < 1e-11, "f64 mass change {change:e} (f32: {change_f32:e})");
    // The initial mass differs by the f32 rounding of the hydrostatic densities alone.
    let (m64, m32) = (s["lbm"]["mass_initial"].as_f64().unwrap(), f32_run["lbm"]["mass_initial"].as_f64().unwrap());
    assert!((m64 - m32).abs() < 1e-6 * m32, "initial mass {m64} against f32's {m32}");
    let fronts = |v: &serde_json::Value| -> Vec<f64> {
        v["liquid_front"].as_array().unwrap().iter().map(|f| f["x_norm"].as_f64().unwrap()).collect()
    };
    let (x64, x32) = (fronts(&s), fronts(&f32_run));
    assert_eq!(x64.len(), x32.len());
    // One cell is 0.05 L0 (2 mm of 40 mm): the fronts may differ by a cell where
    // round-off tips an interface cell's conversion, not more.
    for (a, b) in x64.iter().zip(&x32) {
        assert!((a - b).abs() <= 0.05 + 1e-9, "front f64 {a} against f32 {b}: {x64:?} / {x32:?}");
    }
    let bytes = std::fs::read(out.join("run.mcap")).expect("run.mcap written");
    let (_, state) = lbm_proc::run::LbmState::<f64>::last_of_recording(&bytes).expect("an f64 /lbm/state");
    assert_eq!(state.fluid.dims, [100, 25, 40]);
    assert_eq!(state.fluid.populations.len(), state.fluid.layout().len());
    assert_eq!(state.fluid.layout().len(), 19 * 128 * 25 * 40, "x-rows of 100 cells in one segment of 128");
    let refused = lbm_proc::run::LbmState::last_in_recording(&bytes).unwrap_err();
    assert!(refused.contains("lbm_proc::run::LbmState<f64>") && refused.contains("lbm.precision"), "{refused}");
}
