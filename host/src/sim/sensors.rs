//! Simulating one IMU: its clock gives the true sampling instants, the trajectory gives the
//! kinematics there, the mount moves them to the sensor (lever arm, boresight), and each
//! channel adds its error effects. Samples are computed in fixed-size chunks in parallel
//! (rayon); every random draw comes from a ChaCha stream keyed by seed, sensor, channel
//! and chunk, so the output does not depend on the number of threads.

use std::collections::BTreeSet;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use rayon::prelude::*;

use super::clock::ClockRun;
use super::effects::{sensor_kinematics, ChannelEffects, Mount};
use super::trajectory::Trajectory;
use crate::interchange::{ImuRecording, Triplet};
use crate::model::{Effect, ImuModel};

const CHUNK: usize = 8192;

/// A random stream for one purpose of one sensor.
pub(crate) fn stream(seed: u64, sensor: u64, purpose: u64, index: u64) -> ChaCha8Rng {
    let mut rng = ChaCha8Rng::seed_from_u64(
        seed ^ sensor.wrapping_mul(0x9E37_79B9_7F4A_7C15)
            ^ purpose.wrapping_mul(0xC2B2_AE3D_27D4_EB4F),
    );
    rng.set_stream(index);
    rng
}

/// One simulated IMU.
#[derive(Debug, Clone)]
pub struct ImuRun {
    pub name: String,
    /// The recording as the sensor reports it (t_s in the sensor's own time).
    pub recording: ImuRecording,
    /// The clock as realised (ticks and sampling instants in true time).
    pub clock: ClockRun,
    /// True instant of each sample including the time offset, s.
    pub true_t_s: Vec<f64>,
    /// Error-free sensor-frame outputs at the true instants (gx..az), when kept.
    pub ideal: Option<[Vec<f64>; 6]>,
    /// Effects of each channel as resolved (for the truth file).
    pub channels: Vec<ChannelEffects>,
    pub mount: Mount,
    /// Effects switched off for this sensor (sensor list plus global list).
    pub disabled: BTreeSet<Effect>,
}

/// Options of [`simulate_imu`].
pub struct ImuJob<'a> {
    pub model: &'a ImuModel,
    /// Index of the sensor (0 = reference), keys its random streams.
    pub sensor: u64,
    pub duration_s: f64,
    pub seed: u64,
    /// Effects switched off globally.
    pub disabled: &'a BTreeSet<Effect>,
    /// Also write attitude, position and velocity (the reference IMU).
    pub with_navigation: bool,
    pub keep_ideal: bool,
}

/// What a run of one IMU is set up with before any sample is drawn.
struct ImuSetup {
    /// Number of samples.
    n: usize,
    clock: ClockRun,
    /// True instant of each sample including the time offset, s.
    true_t_s: Vec<f64>,
    mount: Mount,
    channels: Vec<ChannelEffects>,
    /// Effects switched off for this sensor (sensor list plus global list).
    disabled: BTreeSet<Effect>,
}

impl ImuSetup {
    /// Realises the clock (random stream 1) and resolves the mount and the channels' effects.
    fn new(job: &ImuJob) -> Self {
        let model = job.model;
        let n = (job.duration_s * model.rate_hz).floor().max(1.0) as usize;
        let mut disabled: BTreeSet<Effect> = job.disabled.clone();
        disabled.extend(model.disabled.iter().copied());
        let mut clock_rng = stream(job.seed, job.sensor, 1, 0);
        let clock = ClockRun::realise(
            &model.clock,
            model.rate_hz,
            n,
            !disabled.contains(&Effect::ClockDrift),
            !disabled.contains(&Effect::ClockJitter),
            &mut clock_rng,
        );
        let offset = if disabled.contains(&Effect::TimeOffset) {
            0.0
        } else {
            model.time_offset_s
        };
        let true_t_s: Vec<f64> = clock.sample_t_s.iter().map(|t| t - offset).collect();
        let mount = Mount::of(model, &disabled);
        let channels: Vec<ChannelEffects> = (0..6)
            .map(|i| {
                let ch = model.channel(i);
                let mut off = disabled.clone();
                off.extend(ch.disabled.iter().cloned());
                ChannelEffects::resolve(ch, i, model.rate_hz, &off)
            })
            .collect();
        Self {
            n,
            clock,
            true_t_s,
            mount,
            channels,
            disabled,
        }
    }
}

/// The columns a run fills, sample by sample.
struct ImuColumns {
    /// gx .. az: first the stochastic processes, then the whole sensor output.
    out: Vec<Vec<f64>>,
    /// Error-free gx .. az, when kept (else empty).
    ideal: Vec<Vec<f64>>,
    /// Roll, pitch, yaw, latitude, longitude, height, NED velocity, for the reference (else
    /// empty).
    nav: Vec<Vec<f64>>,
}

/// Number of navigation columns of the reference IMU.
const NAV_COLUMNS: usize = 9;

impl ImuColumns {
    /// The stochastic processes of each channel (sequential within a channel, random stream
    /// 2, channels in parallel) and zeroed ideal and navigation columns as `job` asks.
    fn new(setup: &ImuSetup, job: &ImuJob) -> Self {
        let n = setup.n;
        let out: Vec<Vec<f64>> = setup
            .channels
            .par_iter()
            .map(|fx| match &fx.stochastic {
                Some(spec) => {
                    spec.simulate(n, &mut stream(job.seed, job.sensor, 2, fx.index as u64))
                }
                None => vec![0.0; n],
            })
            .collect();
        let ideal: Vec<Vec<f64>> = if job.keep_ideal {
            vec![vec![0.0; n]; 6]
        } else {
            Vec::new()
        };
        let nav_cols = if job.with_navigation { NAV_COLUMNS } else { 0 };
        Self {
            out,
            ideal,
            nav: vec![vec![0.0; n]; nav_cols],
        }
    }

    /// The columns cut into chunks of [`CHUNK`] samples: per chunk, its slice of every
    /// column (output, then ideal, then navigation).
    fn chunks(&mut self, n: usize) -> Vec<Vec<&mut [f64]>> {
        let mut views: Vec<std::slice::ChunksMut<f64>> = self
            .out
            .iter_mut()
            .chain(self.ideal.iter_mut())
            .chain(self.nav.iter_mut())
            .map(|c| c.chunks_mut(CHUNK))
            .collect();
        (0..n.div_ceil(CHUNK))
            .map(|_| {
                views
                    .iter_mut()
                    .map(|v| v.next().unwrap_or_default())
                    .collect()
            })
            .collect()
    }
}

/// Adds the deterministic and per-sample random effects (random streams 3.., keyed by
/// channel and chunk) to the stochastic processes in `cols`, one chunk of samples starting at
/// sample `start`, and fills the chunk's ideal and navigation columns.
fn simulate_chunk(
    traj: &Trajectory,
    job: &ImuJob,
    setup: &ImuSetup,
    chunk: usize,
    cols: &mut [&mut [f64]],
) {
    let start = chunk * CHUNK;
    let len = cols[0].len();
    let mut rngs: Vec<ChaCha8Rng> = (0..6)
        .map(|i| stream(job.seed, job.sensor, 3 + i as u64, chunk as u64))
        .collect();
    for (j, &t) in setup.true_t_s[start..start + len].iter().enumerate() {
        let truth = traj.truth(t);
        let kin = sensor_kinematics(&truth, &setup.mount);
        for (i, fx) in setup.channels.iter().enumerate() {
            let ideal_value = kin.channel(i);
            let mut y = ideal_value + cols[i][j] + fx.deterministic(&kin, t);
            let sigma = fx.dynamic_sigma(&kin);
            if sigma > 0.0 {
                let z: f64 = rngs[i].sample(StandardNormal);
                y += sigma * z;
            }
            if let Some(o) = fx.outliers {
                if o.probability > 0.0 && rngs[i].random_bool(o.probability) {
                    let z: f64 = rngs[i].sample(StandardNormal);
                    y += o.sigma * z;
                }
            }
            cols[i][j] = fx.finish(y);
            if job.keep_ideal {
                cols[6 + i][j] = ideal_value;
            }
        }
        if job.with_navigation {
            let b = if job.keep_ideal { 12 } else { 6 };
            let v = [
                truth.roll_rad,
                truth.pitch_rad,
                truth.yaw_rad,
                truth.lat_rad,
                truth.lon_rad,
                truth.h_m,
                truth.v_ned_m_s.x,
                truth.v_ned_m_s.y,
                truth.v_ned_m_s.z,
            ];
            for (k, x) in v.into_iter().enumerate() {
                cols[b + k][j] = x;
            }
        }
    }
}

/// Simulates one IMU over `[0, duration_s)` of its own time; `progress` is called with the
/// number of samples finished, chunk by chunk.
pub fn simulate_imu(traj: &Trajectory, job: &ImuJob, progress: &(dyn Fn(u64) + Sync)) -> ImuRun {
    let setup = ImuSetup::new(job);
    let mut columns = ImuColumns::new(&setup, job);
    // Deterministic and per-sample random effects, chunk by chunk in parallel.
    columns
        .chunks(setup.n)
        .into_par_iter()
        .enumerate()
        .for_each(|(c, mut cols)| {
            simulate_chunk(traj, job, &setup, c, &mut cols);
            progress(cols[0].len() as u64);
        });
    assemble(job, setup, columns)
}

/// The run's recording (sensor time on the nominal sample grid) from its filled columns.
fn assemble(job: &ImuJob, setup: ImuSetup, columns: ImuColumns) -> ImuRun {
    let model = job.model;
    let dt = 1.0 / model.rate_hz;
    let t_s: Vec<f64> = (0..setup.n).map(|k| k as f64 * dt).collect();
    let take3 = |it: &mut std::vec::IntoIter<Vec<f64>>| -> Triplet {
        [
            it.next().unwrap_or_default(),
            it.next().unwrap_or_default(),
            it.next().unwrap_or_default(),
        ]
    };
    let mut it = columns.out.into_iter();
    let gyro = take3(&mut it);
    let accel = take3(&mut it);
    let mut nav_it = columns.nav.into_iter();
    let (attitude, position, velocity) = if job.with_navigation {
        (
            Some(take3(&mut nav_it)),
            Some(take3(&mut nav_it)),
            Some(take3(&mut nav_it)),
        )
    } else {
        (None, None, None)
    };
    let ideal = if job.keep_ideal {
        let mut it = columns.ideal.into_iter();
        Some(std::array::from_fn(|_| it.next().unwrap_or_default()))
    } else {
        None
    };
    ImuRun {
        name: model.name.clone(),
        recording: ImuRecording {
            t_s,
            gyro_rad_s: Some(gyro),
            accel_m_s2: Some(accel),
            attitude_rad: attitude,
            position,
            velocity_ned_m_s: velocity,
            single_axis: Vec::new(),
            sample_rate_hz: Some(model.rate_hz),
        },
        clock: setup.clock,
        true_t_s: setup.true_t_s,
        ideal,
        channels: setup.channels,
        mount: setup.mount,
        disabled: setup.disabled,
    }
}
