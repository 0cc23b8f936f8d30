//! The DEM ⇄ LBM shared-memory link: values, handshake errors, run-id
//! isolation, dead peers, interrupts, ordering. Every test has its own run id
//! (test name + pid) since tests run in parallel threads and processes.

use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc};
use std::thread;
use std::time::{Duration, Instant};

use runtime::link::*;

/// Counts heap allocations per thread, to check the exchange path makes none of its own.
struct CountingAlloc;

thread_local! {
    static ALLOCS: std::cell::Cell<u64> = const { std::cell::Cell::new(0) };
}

// SAFETY: forwards to the system allocator; the counter is a const-initialised
// thread local, which never allocates.
unsafe impl std::alloc::GlobalAlloc for CountingAlloc {
    unsafe fn alloc(&self, layout: std::alloc::Layout) -> *mut u8 {
        let _ = ALLOCS.try_with(|c| c.set(c.get() + 1));
        // SAFETY: same contract as ours.
        unsafe { std::alloc::System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: std::alloc::Layout) {
        // SAFETY: same contract as ours.
        unsafe { std::alloc::System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: std::alloc::Layout, new_size: usize) -> *mut u8 {
        let _ = ALLOCS.try_with(|c| c.set(c.get() + 1));
        // SAFETY: same contract as ours.
        unsafe { std::alloc::System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: CountingAlloc = CountingAlloc;

fn allocs() -> u64 {
    ALLOCS.with(|c| c.get())
}

const SCENE: u64 = 0x5eed_0000_0000_0001;
const CHILD_ENV: &str = "SGF_LINK_TEST_CHILD_RUN";

fn run_id(test: &str) -> String {
    format!("t-{test}-{}", std::process::id())
}

fn cfg(run: &str, particles: usize) -> LinkConfig {
    let mut c = LinkConfig::new(run, SCENE, particles);
    c.connect_timeout = Duration::from_secs(5);
    c
}

fn state(k: u64, i: usize) -> ParticleState {
    let x = i as f64 * 1e-3 + k as f64;
    ParticleState {
        id: i as u32,
        _pad: 0,
        position: [x, -x, 0.5 * x],
        velocity: [1.0 + x, 2.0, -3.0 * x],
        angular_velocity: [0.1 * x, 0.2, 0.3],
        radius: 1e-3 + i as f64 * 1e-7,
    }
}

/// What the test LBM answers: exact in f64 on both sides.
fn load_of(s: &ParticleState) -> HydroLoad {
    HydroLoad {
        id: s.id,
        _pad: 0,
        force: s.position.map(|p| 2.0 * p),
        torque: s.angular_velocity.map(|w| -w),
        liquid_mass: 1000.0 * s.radius * s.radius * s.radius,
    }
}

/// An LBM that answers `exchanges` exchanges with [`load_of`].
fn echo_lbm(c: LinkConfig, exchanges: u64) -> thread::JoinHandle<Result<(), LinkError>> {
    thread::spawn(move || {
        let mut link = LbmLink::connect(&c)?;
        let mut states = Vec::new();
        let mut loads = Vec::with_capacity(c.particles);
        for k in 0..exchanges {
            let h = link.receive_states(k, &mut states)?;
            assert_eq!(h.count as usize, c.particles);
            assert_eq!(h.time, k as f64 * 1e-4);
            loads.clear();
            loads.extend(states.iter().map(load_of));
            link.send_loads(ExchangeHeader::new(k, h.time), &loads)?;
        }
        Ok(())
    })
}

/// DEM side of `exchanges` round trips with exact checks; returns round-trip times.
fn dem_round_trips(c: &LinkConfig, exchanges: u64) -> Vec<Duration> {
    let n = c.particles;
    let mut dem = DemLink::connect(c).expect("DEM connects");
    let mut states = vec![ParticleState::default(); n];
    let mut loads = Vec::with_capacity(n);
    let mut times = Vec::new();
    for k in 0..exchanges {
        for (i, s) in states.iter_mut().enumerate() {
            *s = state(k, i);
        }
        let t0 = Instant::now();
        dem.send_states(ExchangeHeader::new(k, k as f64 * 1e-4), &states).expect("send states");
        let h = dem.receive_loads(k, &mut loads).expect("receive loads");
        times.push(t0.elapsed());
        assert_eq!(h.exchange, k);
        assert_eq!(h.count as usize, n);
        assert_eq!(loads.len(), n);
        for (i, l) in loads.iter().enumerate() {
            assert_eq!(l.id, i as u32);
            assert_eq!(*l, load_of(&state(k, i)), "grain {i} of exchange {k}");
        }
    }
    times
}

fn percentile(sorted: &[Duration], q: f64) -> Duration {
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}

#[test]
fn round_trip_8000_particles_exact() {
    let c = cfg(&run_id("rt"), 8000);
    let lbm = echo_lbm(c.clone(), 200);
    let mut times = dem_round_trips(&c, 200);
    lbm.join().expect("LBM thread").expect("LBM side");
    times.sort();
    println!(
        "8000 particles, 200 round trips: median {:.1} µs, p99 {:.1} µs, max {:.1} µs",
        percentile(&times, 0.5).as_secs_f64() * 1e6,
        percentile(&times, 0.99).as_secs_f64() * 1e6,
        times[times.len() - 1].as_secs_f64() * 1e6
    );
}

#[test]
fn exchanges_do_not_allocate() {
    // No spin: every receive blocks on the listener (the slow path); the
    // peer check (which lists nodes) stays out of it with a long slice.
    let mut c = cfg(&run_id("alloc"), 1000);
    c.spin = Duration::ZERO;
    c.peer_check = Duration::from_secs(5);
    const WARM: u64 = 3;
    const N: u64 = 50;
    let lc = c.clone();
    let lbm = thread::spawn(move || -> Result<u64, LinkError> {
        let mut link = LbmLink::connect(&lc)?;
        let mut states = Vec::with_capacity(lc.particles);
        let mut loads = vec![HydroLoad::default(); lc.particles];
        let mut before = 0;
        for k in 0..WARM + N {
            if k == WARM {
                before = allocs();
            }
            let h = link.receive_states(k, &mut states)?;
            for (l, s) in loads.iter_mut().zip(&states) {
                *l = load_of(s);
            }
            link.send_loads(ExchangeHeader::new(k, h.time), &loads)?;
        }
        Ok(allocs() - before)
    });
    let mut dem = DemLink::connect(&c).expect("DEM connects");
    let states: Vec<_> = (0..c.particles).map(|i| state(0, i)).collect();
    let mut loads = Vec::with_capacity(c.particles);
    let mut before = 0;
    for k in 0..WARM + N {
        if k == WARM {
            before = allocs();
        }
        dem.send_states(ExchangeHeader::new(k, 0.0), &states).expect("send");
        dem.receive_loads(k, &mut loads).expect("receive");
    }
    let dem_allocs = allocs() - before;
    let lbm_allocs = lbm.join().expect("LBM thread").expect("LBM side");
    // The link itself allocates nothing; iceoryx2 0.10's loan allocates one
    // small Rc per message (the sample's shared state), hence at most N.
    assert!(
        dem_allocs <= N && lbm_allocs <= N,
        "heap allocations in {N} exchanges: DEM {dem_allocs}, LBM {lbm_allocs}"
    );
    println!("heap allocations in {N} exchanges: DEM {dem_allocs}, LBM {lbm_allocs} (one per loan, inside iceoryx2)");
}

/// Connects a DEM (this thread) and an LBM (another thread) with the given
/// configs; returns both results.
fn connect_both(dem: LinkConfig, lbm: LinkConfig) -> (Result<DemLink, LinkError>, Result<(), LinkError>) {
    let t = thread::spawn(move || LbmLink::connect(&lbm).map(|_| ()));
    let d = DemLink::connect(&dem);
    (d, t.join().expect("LBM thread"))
}

#[test]
fn protocol_mismatch_on_both_sides() {
    let run = run_id("proto");
    let mut dem = cfg(&run, 10);
    dem.protocol_version_override = Some(PROTOCOL_VERSION + 1);
    let (d, l) = connect_both(dem, cfg(&run, 10));
    match d {
        Err(LinkError::ProtocolMismatch { ours, theirs }) => {
            assert_eq!((ours, theirs), (PROTOCOL_VERSION + 1, PROTOCOL_VERSION))
        }
        Err(e) => panic!("DEM: {e}"),
        Ok(_) => panic!("DEM connected"),
    }
    let e = l.expect_err("LBM must fail");
    assert!(
        matches!(e, LinkError::ProtocolMismatch { ours, theirs } if ours == PROTOCOL_VERSION && theirs == PROTOCOL_VERSION + 1),
        "{e}"
    );
    assert!(e.to_string().contains("rebuild both binaries from the same source"), "{e}");
}

#[test]
fn scene_mismatch_on_both_sides() {
    let run = run_id("scene");
    let mut lbm = cfg(&run, 10);
    lbm.scene_hash = SCENE + 7;
    let (d, l) = connect_both(cfg(&run, 10), lbm);
    match d {
        Err(LinkError::SceneMismatch { ours, theirs }) => assert_eq!((ours, theirs), (SCENE, SCENE + 7)),
        Err(e) => panic!("DEM: {e}"),
        Ok(_) => panic!("DEM connected"),
    }
    let e = l.expect_err("LBM must fail");
    assert!(matches!(e, LinkError::SceneMismatch { ours, theirs } if ours == SCENE + 7 && theirs == SCENE), "{e}");
    assert!(e.to_string().contains("same scene file and the same --set overrides"), "{e}");
}

#[test]
fn run_ids_never_cross() {
    let a = run_id("a");
    let b = run_id("b");
    let stop = Arc::new(AtomicBool::new(false));
    let mut lbm_b = cfg(&b, 10);
    lbm_b.stop = Some(stop.clone());
    let lbm = thread::spawn(move || LbmLink::connect(&lbm_b).map(|_| ()));
    thread::sleep(Duration::from_millis(50));

    let mut dem_a = cfg(&a, 10);
    dem_a.connect_timeout = Duration::from_millis(300);
    let t0 = Instant::now();
    let e = DemLink::connect(&dem_a).err().expect("no LBM on run a");
    let waited = t0.elapsed();
    stop.store(true, Ordering::Relaxed);
    assert!(matches!(&e, LinkError::NoPeer { run_id, role: Role::Lbm, .. } if *run_id == a), "{e}");
    assert!(waited >= Duration::from_millis(300) && waited < Duration::from_secs(2), "{waited:?}");
    let msg = e.to_string();
    assert!(msg.contains(&format!("--run-id {a}")), "{msg}");
    assert!(msg.contains(&b), "the message lists the live run {b}: {msg}");
    assert!(matches!(lbm.join().expect("LBM thread"), Err(LinkError::Interrupted)));
}

/// Child half of [`dead_peer_then_fresh_pair`]: an LBM that receives
/// exchange 0 and then SIGKILLs itself. Does nothing in a normal test run.
#[test]
fn child_lbm_that_dies() {
    let Ok(run) = std::env::var(CHILD_ENV) else { return };
    let mut link = LbmLink::connect(&cfg(&run, 100)).expect("child LBM connects");
    let mut states = Vec::new();
    link.receive_states(0, &mut states).expect("child receives exchange 0");
    // SAFETY: kill on our own pid; nothing runs after it.
    unsafe {
        libc::kill(libc::getpid(), libc::SIGKILL);
    }
}

#[test]
fn dead_peer_then_fresh_pair() {
    let run = run_id("dead");
    let mut child = Command::new(std::env::current_exe().expect("test binary"))
        .args(["--exact", "child_lbm_that_dies", "--nocapture", "--test-threads=1"])
        .env(CHILD_ENV, &run)
        .stdout(Stdio::null())
        .spawn()
        .expect("spawn child LBM");
    let c = cfg(&run, 100);
    let mut dem = DemLink::connect(&c).expect("DEM connects to the child");
    assert_eq!(dem.peer_pid(), child.id());
    let states: Vec<_> = (0..100).map(|i| state(0, i)).collect();
    dem.send_states(ExchangeHeader::new(0, 0.0), &states).expect("send exchange 0");
    let mut loads = Vec::new();
    let t0 = Instant::now();
    let e = dem.receive_loads(0, &mut loads).expect_err("the child dies");
    let noticed = t0.elapsed();
    assert!(matches!(&e, LinkError::PeerDead { role: Role::Lbm, pid, .. } if *pid == child.id()), "{e}");
    assert!(noticed < Duration::from_secs(2), "noticed after {noticed:?}");
    println!("dead peer noticed after {:.0} ms: {e}", noticed.as_secs_f64() * 1e3);
    let status = child.wait().expect("child status");
    assert!(!status.success());
    drop(dem);

    // A fresh pair on the same run id is not blocked by the dead node's leftovers.
    let lbm = echo_lbm(c.clone(), 3);
    let times = dem_round_trips(&c, 3);
    assert_eq!(times.len(), 3);
    lbm.join().expect("LBM thread").expect("fresh LBM");
}

#[test]
fn stop_flag_interrupts_a_wait() {
    let run = run_id("stop");
    let (done_tx, done_rx) = mpsc::channel::<()>();
    let c = cfg(&run, 10);
    let lbm_cfg = c.clone();
    // An LBM that connects and then never answers.
    let lbm = thread::spawn(move || {
        let link = LbmLink::connect(&lbm_cfg);
        let _ = done_rx.recv();
        link.map(|_| ())
    });
    let stop = Arc::new(AtomicBool::new(false));
    let mut dc = c.clone();
    dc.stop = Some(stop.clone());
    let mut dem = DemLink::connect(&dc).expect("DEM connects");
    let raise = {
        let stop = stop.clone();
        thread::spawn(move || {
            // Mid-slice: the wait blocks in slices of peer_check = 100 ms.
            thread::sleep(Duration::from_millis(150));
            stop.store(true, Ordering::Relaxed);
            Instant::now()
        })
    };
    let mut loads = Vec::new();
    let e = dem.receive_loads(0, &mut loads).expect_err("interrupted");
    let returned = Instant::now();
    let raised = raise.join().expect("timer thread");
    let late = returned - raised;
    assert!(matches!(e, LinkError::Interrupted), "{e}");
    assert!(late < Duration::from_millis(200), "returned {late:?} after the flag");
    println!("interrupted {:.1} ms after the flag", late.as_secs_f64() * 1e3);
    done_tx.send(()).expect("LBM thread alive");
    lbm.join().expect("LBM thread").expect("LBM connected");
}

#[test]
fn out_of_order_exchange_is_reported() {
    let run = run_id("order");
    let c = cfg(&run, 10);
    let lbm_cfg = c.clone();
    let lbm = thread::spawn(move || {
        let mut link = LbmLink::connect(&lbm_cfg)?;
        let mut states = Vec::new();
        link.receive_states(1, &mut states).map(|_| ())
    });
    let mut dem = DemLink::connect(&c).expect("DEM connects");
    let states: Vec<_> = (0..10).map(|i| state(0, i)).collect();
    dem.send_states(ExchangeHeader::new(0, 0.0), &states).expect("send exchange 0");
    let e = lbm.join().expect("LBM thread").expect_err("LBM expected exchange 1");
    assert!(matches!(e, LinkError::OutOfOrder { expected: 1, got: 0, .. }), "{e}");
    assert!(e.to_string().contains("send_states(1)"), "{e}");
}

#[test]
fn wrong_count_and_stop_message() {
    let run = run_id("count");
    let c = cfg(&run, 10);
    let lbm_cfg = c.clone();
    let lbm = thread::spawn(move || {
        let mut link = LbmLink::connect(&lbm_cfg).expect("LBM connects");
        let mut states = Vec::new();
        link.receive_states(0, &mut states).expect_err("DEM stops")
    });
    let mut dem = DemLink::connect(&c).expect("DEM connects");
    let states: Vec<_> = (0..9).map(|i| state(0, i)).collect();
    let e = dem.send_states(ExchangeHeader::new(0, 0.0), &states).expect_err("9 instead of 10");
    assert!(matches!(e, LinkError::SendLength { exchange: 0, expected: 10, got: 9, .. }), "{e}");
    assert!(e.to_string().starts_with("send_states(0) got 9 entries"), "{e}");
    dem.send_stop(0, 0.0).expect("send stop");
    let e = lbm.join().expect("LBM thread");
    assert!(matches!(e, LinkError::PeerStopped { role: Role::Dem, exchange: 0 }), "{e}");
}

#[test]
fn second_dem_on_a_run_id_is_refused() {
    let run = run_id("twice");
    let stop = Arc::new(AtomicBool::new(false));
    let mut first = cfg(&run, 10);
    first.stop = Some(stop.clone());
    let t = thread::spawn(move || DemLink::connect(&first).map(|_| ()));
    thread::sleep(Duration::from_millis(100));
    let e = DemLink::connect(&cfg(&run, 10)).err().expect("second DEM refused");
    stop.store(true, Ordering::Relaxed);
    assert!(matches!(&e, LinkError::RoleTaken { role: Role::Dem, pid, .. } if *pid == std::process::id()), "{e}");
    assert!(matches!(t.join().expect("first DEM thread"), Err(LinkError::Interrupted)));
}

#[test]
fn late_peer_still_connects_either_order() {
    for lbm_first in [true, false] {
        let run = run_id(if lbm_first { "late-dem" } else { "late-lbm" });
        let c = cfg(&run, 5);
        let lbm_cfg = c.clone();
        let lbm = thread::spawn(move || {
            if !lbm_first {
                thread::sleep(Duration::from_millis(200));
            }
            let mut link = LbmLink::connect(&lbm_cfg)?;
            let mut states = Vec::new();
            let h = link.receive_states(0, &mut states)?;
            let loads: Vec<_> = states.iter().map(load_of).collect();
            link.send_loads(h, &loads)
        });
        if lbm_first {
            thread::sleep(Duration::from_millis(200));
        }
        let mut dem = DemLink::connect(&c).expect("DEM connects");
        let states: Vec<_> = (0..5).map(|i| state(0, i)).collect();
        dem.send_states(ExchangeHeader::new(0, 0.0), &states).expect("send");
        let mut loads = Vec::new();
        let got = dem.receive_loads(0, &mut loads);
        lbm.join().expect("LBM thread").expect("LBM side");
        got.expect("receive");
        assert_eq!(loads, states.iter().map(load_of).collect::<Vec<_>>());
    }
}

/// The current disposition of `sig` (handler address, SIG_DFL or SIG_IGN).
fn disposition(sig: libc::c_int) -> libc::sighandler_t {
    // SAFETY: reads the current disposition only (null new action).
    unsafe {
        let mut old: libc::sigaction = std::mem::zeroed();
        assert_eq!(libc::sigaction(sig, std::ptr::null(), &mut old), 0);
        old.sa_sigaction
    }
}

/// iceoryx2 must leave SIGINT/SIGTERM to our own handlers (signal_hook
/// flag): connecting does not change their disposition. (Compared with the
/// one before, not with SIG_DFL: a test run started in the background by a
/// non-interactive shell inherits SIGINT ignored.)
#[test]
fn no_signal_handlers_installed() {
    let before = [disposition(libc::SIGINT), disposition(libc::SIGTERM)];
    let c = cfg(&run_id("sig"), 5);
    let lc = c.clone();
    let lbm = thread::spawn(move || {
        let mut link = LbmLink::connect(&lc)?;
        let mut states = Vec::new();
        link.receive_states(0, &mut states).map(|_| ())
    });
    let mut dem = DemLink::connect(&c).expect("DEM connects");
    dem.send_states(ExchangeHeader::new(0, 0.0), &[ParticleState::default(); 5]).expect("send");
    lbm.join().expect("LBM thread").expect("LBM side");
    for (sig, before) in [libc::SIGINT, libc::SIGTERM].into_iter().zip(before) {
        assert!(before == libc::SIG_DFL || before == libc::SIG_IGN, "signal {sig} had a handler before connecting");
        assert_eq!(disposition(sig), before, "signal {sig} has a handler after connecting");
    }
}

#[test]
fn run_id_validation() {
    assert!(validate_run_id("collapse_01-a").is_ok());
    for bad in ["", "a/b", "a b", "ä", &"x".repeat(41)] {
        let e = validate_run_id(bad).expect_err(bad);
        assert!(e.to_string().contains("1 to 40 characters"), "{e}");
    }
    assert!(matches!(DemLink::connect(&cfg("no/slash", 1)), Err(LinkError::InvalidRunId { .. })));
}
