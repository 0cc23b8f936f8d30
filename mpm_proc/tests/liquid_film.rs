//! The laminar film's wall shear on the liquid (`mpm.liquid_wall_shear`,
//! `Mpm::apply_liquid_wall_shear`; docs/mpm.md, "The liquid's wall
//! shear") against Nusselt's film (Bird, Stewart & Lightfoot, *Transport
//! Phenomena*, §2.2): a film of depth d over a no-slip floor has the wall
//! shear τ = 3 μ Ū / d, so its depth-averaged velocity Ū obeys
//! dŪ/dt = g sin θ − Ū / T with T = d² / (3 ν). Released at U0 on a level
//! floor it decays as U0 e^(−t/T); on a slope it reaches Nusselt's
//! U_N = g sin θ d² / (3 ν). Between two walls a gap W apart the flow
//! is plane Poiseuille's, with each wall's shear 6 μ Ū / W:
//! dŪ/dt = −12 ν Ū / W².

mod common;

use mpm_proc::solver::Mpm;

const G: f64 = 9.81;
const RHO: f64 = 1000.0;
/// A syrup (ν = 1e-4 m²/s), so that the film's time T = d²/(3ν) = 53 ms
/// fits a short test; water's would be 5 s.
const MU: f64 = 0.1;
/// Film: length and depth, m (two 2 mm elements deep).
const LENGTH: f64 = 0.2;
const DEPTH: f64 = 0.004;

fn film_time() -> f64 {
    DEPTH * DEPTH / (3.0 * MU / RHO)
}

/// A block of the syrup `width` × `height` m standing on the floor of a
/// box as wide, on elements of `element` m, with the given `[mpm]` lines.
/// The bulk modulus is a tenth of the lab's: the block stays within 1e-5
/// of its volume and the step is three times longer.
fn syrup(width: f64, height: f64, element: f64, mpm: &str) -> Mpm {
    let mut m = common::free_water_column(
        width,
        height,
        RHO,
        &format!("element_size = {element}\nliquid_bulk_modulus = 2.0e6\ndamping = 0.0\n{mpm}"),
    );
    m.params.viscosity = MU;
    m.params.drag.viscosity = MU;
    m
}

/// A film LENGTH × DEPTH on 2 mm elements under gravity tilted by
/// `slope` (sin θ), with the given `[mpm]` lines.
fn film(slope: f64, mpm: &str) -> Mpm {
    let mut m = syrup(LENGTH, DEPTH, 0.002, mpm);
    m.params.gravity = [G * slope, -G * (1.0 - slope * slope).sqrt()];
    m
}

/// Mass-weighted mean velocity along `axis` of the points whose
/// coordinate along it lies in `within`, m/s.
fn mean_velocity(m: &Mpm, axis: usize, within: std::ops::Range<f64>) -> f64 {
    let l = &m.state.liquid.set;
    let (mut momentum, mut mass) = (0.0, 0.0);
    for p in 0..l.len() {
        if within.contains(&l.x[p][axis]) {
            momentum += l.mass[p] * l.v[p][axis];
            mass += l.mass[p];
        }
    }
    momentum / mass
}

/// The film's mean x-velocity over its middle third. The waves from its
/// ends (the bore where it runs into the far wall) reached the middle
/// third of a 0.15 m film by 0.11 s; they do not reach this one's within
/// the tests' 0.16 s.
fn middle_velocity(m: &Mpm) -> f64 {
    mean_velocity(m, 0, LENGTH / 3.0..2.0 * LENGTH / 3.0)
}

fn run_to(m: &mut Mpm, t: f64) {
    while m.state.time < t - 0.5 * m.params.dt {
        m.step();
    }
}

#[test]
fn a_film_released_on_a_level_floor_slows_as_nusselts_wall_shear_says() {
    let (u0, t) = (0.05, film_time());
    let mut m = film(0.0, "");
    m.state.liquid.set.set_velocity([u0, 0.0]);
    run_to(&mut m, t);
    let at_t = middle_velocity(&m) / u0;
    run_to(&mut m, 2.0 * t);
    let at_2t = middle_velocity(&m) / u0;
    eprintln!("U/U0 {at_t:.4} at T (e^-1 = {:.4}), {at_2t:.4} at 2T (e^-2 = {:.4})", (-1.0f64).exp(), (-2.0f64).exp());
    // The film is uniform away from its ends and the depth its nodes' mass
    // stands for is exact to the compression (1e-5); backward Euler's
    // error at Δt/T = 4e-4 is 2e-4 of the decay at T. 1 % allows the settling
    // of the stress-free start (its pressure wave crosses 4 mm in 0.1 ms).
    assert!((at_t / (-1.0f64).exp() - 1.0).abs() < 0.01, "U/U0 = {at_t} at T, e^-1 expected");
    assert!((at_2t / (-2.0f64).exp() - 1.0).abs() < 0.01, "U/U0 = {at_2t} at 2T, e^-2 expected");

    // Free slip, as before: nothing slows it.
    let mut slip = film(0.0, "liquid_wall_shear = \"none\"");
    slip.state.liquid.set.set_velocity([u0, 0.0]);
    run_to(&mut slip, t);
    let free = middle_velocity(&slip) / u0;
    assert!((free - 1.0).abs() < 0.01, "U/U0 = {free} at T under free slip, 1 expected");
}

/// A film a third of an element deep (one row of points on 4 mm
/// elements, d = 1.33 mm), the films the wall law is for, released at U0:
/// T = d²/(3ν) = 5.9 ms. Its step is 0.8 % of T, so the expected values
/// are backward Euler's (1 + Δt/T)^(−t/Δt), 0.4 % and 0.8 % above e⁻¹
/// and e⁻²; the bar is 0.5 % of them.
#[test]
fn a_film_thinner_than_an_element_slows_as_nusselts_wall_shear_says() {
    let (h, u0) = (0.004, 0.05);
    let depth = h / 3.0;
    let t = depth * depth / (3.0 * MU / RHO);
    let mut m = syrup(LENGTH, depth, h, "");
    m.state.liquid.set.set_velocity([u0, 0.0]);
    let dt = m.params.dt;
    let backward_euler = |time: f64| (1.0 + dt / t).powf(-time / dt);
    run_to(&mut m, t);
    let (at_t, expected_t) = (middle_velocity(&m) / u0, backward_euler(m.state.time));
    run_to(&mut m, 2.0 * t);
    let (at_2t, expected_2t) = (middle_velocity(&m) / u0, backward_euler(m.state.time));
    eprintln!("sub-element film: U/U0 {at_t:.4} ({expected_t:.4}) at T, {at_2t:.4} ({expected_2t:.4}) at 2T");
    assert!((at_t / expected_t - 1.0).abs() < 0.005, "U/U0 = {at_t} at T, {expected_t} expected");
    assert!((at_2t / expected_2t - 1.0).abs() < 0.005, "U/U0 = {at_2t} at 2T, {expected_2t} expected");
}

/// Water filling a vertical channel W = 8 mm wide between the side walls
/// (x_min and x_max, four 2 mm elements), 0.1 m tall and lifted 5 mm
/// off the floor, gravity off, released upward at U0: both walls' lines
/// reach the opposite wall, and together they give Poiseuille's
/// 12 ν / W², T = W²/(12ν) = 53 ms. With each wall's film law over the
/// whole gap (3 ν / W² each) T would be twice that. The column's end
/// rows are only partly covered; a line that reaches the opposite wall
/// takes the gap for its depth (taking its nodal mass's depth, a fraction
/// of W there, the column was at 0.3514 U0 at T; 0.3588 standing on the
/// floor, with one free end).
#[test]
fn water_between_two_walls_slows_as_plane_poiseuille_flow() {
    let (width, height, u0) = (0.008, 0.1, 0.05);
    let t = width * width / (12.0 * MU / RHO);
    let mut m = syrup(width, height, 0.002, "");
    m.params.gravity = [0.0, 0.0];
    let lift = 0.005;
    for x in &mut m.state.liquid.set.x {
        x[1] += lift;
    }
    m.state.liquid.set.set_velocity([0.0, u0]);
    run_to(&mut m, t);
    let at_t = mean_velocity(&m, 1, lift + height / 3.0..lift + 2.0 * height / 3.0) / u0;
    eprintln!("channel: U/U0 {at_t:.4} at T (e^-1 = {:.4})", (-1.0f64).exp());
    assert!((at_t / (-1.0f64).exp() - 1.0).abs() < 0.01, "U/U0 = {at_t} at T, e^-1 expected");
}

#[test]
fn a_film_on_a_slope_reaches_nusselts_velocity() {
    let slope = 0.04;
    let (t, u_nusselt) = (film_time(), G * 0.04 * film_time());
    let mut m = film(slope, "");
    run_to(&mut m, 3.0 * t);
    let u = middle_velocity(&m);
    // From rest: Ū = U_N (1 − e^(−t/T)), 0.950 U_N at 3 T. Free slip
    // would give g sin θ t = 3 U_N.
    let expected = u_nusselt * (1.0 - (-3.0f64).exp());
    eprintln!("U = {u:.5} m/s at 3T, Nusselt {u_nusselt:.5} (x 0.950 = {expected:.5})");
    assert!((u / expected - 1.0).abs() < 0.01, "U = {u} m/s at 3 T, {expected} expected");
}

/// A film of the syrup 4 mm deep and 0.1 m long in the middle of a
/// 0.2 m floor (2 mm elements), released at U0 along the floor: its ends
/// are free. The node at each end carries about half the mass of a
/// covered one (its strip is half covered) and the node past it a sliver,
/// so a depth read from a line's mass alone slows the ends too fast
/// (session 45's rule: the rear and front elements at 0.135 and 0.161 U0
/// at T, the whole film 0.347). Read as the points' water volume over the
/// length of the strip they cover, the line past the end taking the
/// end's depth, every line has the film's depth: 0.3680 U0 at both ends,
/// in the middle and over the whole film, with the ends on the strips'
/// edges and with the film shifted 0.9 mm (the rear end's strip 0.05 h
/// covered, the front leaving its strip at once). Gravity is
/// off, so the film does not spread, and the floor holds both ways: with
/// nothing pressing the film onto a unilateral floor, the floor lets go
/// in some steps and the film then feels no wall (the middle at 0.47 U0
/// at T instead of e⁻¹). Bar 1 %, as the uniform film's.
#[test]
fn a_films_free_ends_slow_as_its_middle() {
    // Ends on element boundaries (each end line's strip half covered),
    // then shifted by 0.9 mm: the rear end's strip 0.05 h covered, the
    // front end's 0.95 h, which it leaves at once for the next strip, so
    // both ends cross strip edges as the film moves.
    for shift in [0.0, 0.0009] {
        free_ends_shifted_by(shift);
    }
}

fn free_ends_shifted_by(shift: f64) {
    let (u0, t) = (0.05, film_time());
    let text = format!(
        r#"
[scene]
name = "film_with_free_ends"
method = "mpm"

[domain]
min = [0.0, 0.0, 0.0]
max = [0.2, 0.05, 0.12]
gravity = [0.0, 0.0, -9.81]
walls = ["x_min", "x_max", "z_min"]

[[fluids]]
name = "syrup"
density = {RHO}
viscosity = {MU}
region = {{ min = [0.05, 0.0, 0.0], max = [0.15, 0.05, {DEPTH}] }}

[mpm]
element_size = 0.002
liquid_bulk_modulus = 2.0e6
damping = 0.0
initial_stress = "zero"
floor = "frictional"
wall_contact = "bilateral"

[output]
end_time = 0.2
record_interval = 0.01
stop_at_rest = false

[analysis]
column_length = 0.1
column_height = {DEPTH}
condition = "liquid"
"#
    );
    let scene = schemas::Scene::from_toml_str(&text, std::path::Path::new("."), &[]).expect("film scene");
    let mut m = mpm_proc::setup::build(&scene).expect("film builds").mpm;
    m.params.gravity = [0.0, 0.0];
    m.state.liquid.set.x.iter_mut().for_each(|x| x[0] += shift);
    m.state.liquid.set.set_velocity([u0, 0.0]);
    run_to(&mut m, t);
    let (lo, hi) = m.state.liquid.set.x.iter().fold((f64::MAX, f64::MIN), |(lo, hi), x| (lo.min(x[0]), hi.max(x[0])));
    let (rear, front) = (mean_velocity(&m, 0, lo..lo + 0.002) / u0, mean_velocity(&m, 0, hi - 0.002..hi + 1e-9) / u0);
    let (middle, whole) = (mean_velocity(&m, 0, lo + 0.03..hi - 0.03) / u0, mean_velocity(&m, 0, lo..hi + 1e-9) / u0);
    let e = (-1.0f64).exp();
    eprintln!("film shifted {shift} m with free ends at T: rear {rear:.4}, middle {middle:.4}, front {front:.4}, whole {whole:.4} (e^-1 = {e:.4})");
    for (name, u) in [("rear end", rear), ("middle", middle), ("front end", front), ("whole film", whole)] {
        assert!((u / e - 1.0).abs() < 0.01, "film shifted {shift} m, {name}: U/U0 = {u} at T, e^-1 = {e} expected");
    }
}
