use super::*;
use crate::log::{PpsEvent, IMU_MODEL_LEN};
use crate::recorder::GnssChunk;
use crate::replay::GNSS_CHUNK_MAX;

const RATE_HZ: u64 = 100;
const GYRO_SCALE: f64 = 1e-4;
const ACCEL_SCALE: f64 = 1e-3;
/// First event's time on the source's timescale, us: the plan's times count from it.
const T0_US: u64 = 5_000_000;

fn imus() -> std::vec::Vec<ImuConfig> {
    (0..3)
        .map(|id| ImuConfig {
            imu_id: 10 + id,
            model: heapless::String::<IMU_MODEL_LEN>::new(),
            sample_rate_hz: RATE_HZ as f32,
            gyro_scale_rad_s_per_count: GYRO_SCALE,
            accel_scale_m_s2_per_count: ACCEL_SCALE,
        })
        .collect()
}

/// `seconds` of three units at 100 Hz (counts that change every sample, some negative), a
/// PPS edge each second and a receiver chunk each 100 ms.
fn events(seconds: u64) -> std::vec::Vec<SourceEvent> {
    let mut out = std::vec::Vec::new();
    for k in 0..seconds * RATE_HZ {
        let t_us = T0_US + k * 1_000_000 / RATE_HZ;
        if k % RATE_HZ == 0 {
            out.push(SourceEvent::Pps(PpsEvent {
                t_us,
                sequence: (k / RATE_HZ) as u32,
            }));
        }
        if k % 10 == 0 {
            out.push(SourceEvent::Gnss(GnssChunk {
                t_us,
                len: GNSS_CHUNK_MAX as u8,
                data: [0x55; GNSS_CHUNK_MAX],
            }));
        }
        for unit in 0..3u8 {
            let c = k as i32 * 7 - 300 + i32::from(unit);
            out.push(SourceEvent::Imu(ImuSampleSet {
                t_us: t_us + u64::from(unit),
                imu_id: 10 + unit,
                gyro_counts: [c, -c, c / 2],
                accel_counts: [c + 1, 2 * c, -9810],
            }));
        }
    }
    out
}

struct Events(std::vec::IntoIter<SourceEvent>);

impl SampleSource for Events {
    type Error = ();
    fn next_event(&mut self) -> Result<Option<SourceEvent>, ()> {
        Ok(self.0.next())
    }
}

fn injected(plan: &str, seconds: u64) -> (std::vec::Vec<SourceEvent>, u32) {
    let plan = FaultPlan::parse(plan.as_bytes()).unwrap();
    let clock = InjectionClock::new();
    let mut source =
        InjectingSource::new(Events(events(seconds).into_iter()), plan, &imus(), &clock);
    let mut out = std::vec::Vec::new();
    while let Some(event) = source.next_event().unwrap() {
        out.push(event);
    }
    (out, source.samples_overrun())
}

fn samples_of(events: &[SourceEvent], imu_id: u8) -> std::vec::Vec<ImuSampleSet> {
    events
        .iter()
        .filter_map(|e| match e {
            SourceEvent::Imu(s) if s.imu_id == imu_id => Some(*s),
            _ => None,
        })
        .collect()
}

fn within(t_us: u64, from_s: f64, to_s: f64) -> bool {
    let us = |s: f64| (s * 1e6).round() as u64;
    (us(from_s)..us(to_s)).contains(&(t_us - T0_US))
}

#[test]
fn a_plan_reads_every_kind_with_its_fields_and_times() {
    let plan = FaultPlan::parse(
        b"# a day of trouble\nseed=7\n\
          imu-silent unit=1 from=40 to=70\n\
          imu-stuck unit=2 from=100 to=115   # frozen\n\
          imu-saturated unit=0 from=130 to=132 gyro_rad_s=8.7\n\
          imu-late unit=1 from=150 to=170 delay_us=7000\n\
          spi-errors unit=2 from=190 to=220 rate=0.05\n\
          pps-lost from=240 to=420\n\
          gnss-corrupt from=250 to=280 rate=0.002\n\
          gnss-absent from=300 to=360\n\
          log-full from=380 to=383.5\n\
          hang at=400\n",
    )
    .unwrap();
    assert_eq!(plan.seed, 7);
    assert_eq!(plan.faults.len(), 10);
    assert_eq!(plan.faults[0].action, FaultAction::ImuSilent { unit: 1 });
    assert_eq!(
        (plan.faults[0].from_us, plan.faults[0].to_us),
        (40_000_000, 70_000_000)
    );
    assert_eq!(plan.faults[1].line, 4);
    assert_eq!(
        plan.faults[2].action,
        FaultAction::ImuSaturated {
            unit: 0,
            gyro_rad_s: 8.7,
            accel_m_s2: DEFAULT_ACCEL_RAIL_M_S2
        }
    );
    assert_eq!(plan.faults[8].to_us, 383_500_000);
    assert_eq!(plan.hang_at_s(), Some(400.0));
    assert!(plan.check_units(3).is_ok());
    assert_eq!(
        plan.check_units(2),
        Err(PlanError::NoSuchUnit {
            line: 4,
            unit: 2,
            units: 2
        })
    );
}

#[test]
fn a_bad_plan_is_refused_naming_its_line_and_field() {
    let cases: [(&str, PlanError); 8] = [
        (
            "imu-melt unit=1 from=1 to=2",
            PlanError::UnknownKind { line: 1 },
        ),
        (
            "\nimu-stuck from=1 to=2",
            PlanError::Missing {
                line: 2,
                field: "unit",
            },
        ),
        (
            "spi-errors unit=0 from=1 to=2 rate=1.5",
            PlanError::BadValue {
                line: 1,
                field: "rate",
            },
        ),
        ("pps-lost from=5 to=5", PlanError::Empty { line: 1 }),
        (
            "pps-lost from=5 to=9 colour=red",
            PlanError::UnknownField { line: 1 },
        ),
        (
            "imu-late unit=0 from=1 to=2 delay_us=90000",
            PlanError::BadValue {
                line: 1,
                field: "delay_us",
            },
        ),
        (
            "log-full from=-3 to=2",
            PlanError::BadValue {
                line: 1,
                field: "from",
            },
        ),
        (
            "gnss-absent from=1",
            PlanError::Missing {
                line: 1,
                field: "to",
            },
        ),
    ];
    for (text, expected) in cases {
        assert_eq!(FaultPlan::parse(text.as_bytes()), Err(expected), "{text}");
    }
    let message = std::format!(
        "{}",
        PlanError::Missing {
            line: 2,
            field: "unit"
        }
    );
    assert_eq!(message, "line 2: `unit` missing");
    assert_eq!(FaultPlan::parse(&[0xff, 0xfe]), Err(PlanError::NotUtf8));
}

#[test]
fn a_silent_unit_loses_exactly_its_samples_in_the_window() {
    let (out, overrun) = injected("imu-silent unit=1 from=2 to=3.5", 5);
    let clean = events(5);
    let unit1 = samples_of(&out, 11);
    assert_eq!(unit1.len(), 500 - 150);
    assert!(unit1.iter().all(|s| !within(s.t_us, 2.0, 3.5)));
    assert_eq!(samples_of(&out, 10), samples_of(&clean, 10));
    assert_eq!(samples_of(&out, 12), samples_of(&clean, 12));
    // Silence is no failed read: nothing is counted.
    assert_eq!(overrun, 0);
}

#[test]
fn a_stuck_unit_repeats_its_last_sample_and_a_saturated_one_reads_its_rails() {
    let (out, _) = injected(
        "imu-stuck unit=2 from=1 to=2\nimu-saturated unit=0 from=3 to=3.2 gyro_rad_s=3 accel_m_s2=100",
        5,
    );
    let clean = samples_of(&events(5), 12);
    let unit2 = samples_of(&out, 12);
    let before = clean.iter().rfind(|s| within(s.t_us, 0.0, 1.0)).unwrap();
    for (s, c) in unit2.iter().zip(&clean) {
        assert_eq!(s.t_us, c.t_us);
        if within(s.t_us, 1.0, 2.0) {
            assert_eq!(
                (s.gyro_counts, s.accel_counts),
                (before.gyro_counts, before.accel_counts)
            );
        } else {
            assert_eq!(s, c);
        }
    }
    let unit0 = samples_of(&out, 10);
    let saturated: std::vec::Vec<_> = unit0.iter().filter(|s| within(s.t_us, 3.0, 3.2)).collect();
    assert_eq!(saturated.len(), 20);
    for s in saturated {
        // 3 rad/s at 1e-4 rad/s a count, 100 m/s^2 at 1e-3: the signs are the reading's when the fault began.
        assert!(s.gyro_counts.iter().all(|c| c.abs() == 30_000));
        assert_eq!(s.gyro_counts[0], -s.gyro_counts[1]);
        assert_eq!(s.accel_counts[2], -100_000);
    }
}

#[test]
fn late_samples_come_in_time_order_and_none_is_lost() {
    let (out, _) = injected("imu-late unit=1 from=1 to=3 delay_us=7000", 4);
    let times: std::vec::Vec<u64> = out.iter().map(SourceEvent::t_us).collect();
    assert!(times.windows(2).all(|w| w[0] <= w[1]), "out of order");
    let clean = samples_of(&events(4), 11);
    let late = samples_of(&out, 11);
    assert_eq!(late.len(), clean.len());
    for (s, c) in late.iter().zip(&clean) {
        let delay = if within(c.t_us, 1.0, 3.0) { 7000 } else { 0 };
        assert_eq!(s.t_us, c.t_us + delay);
        assert_eq!(s.gyro_counts, c.gyro_counts);
    }
    assert_eq!(out.len(), events(4).len());
}

#[test]
fn spi_errors_lose_their_share_of_reads_counted_flagged_and_seeded() {
    let plan = "seed=3\nspi-errors unit=2 from=0 to=40 rate=0.25";
    let (out, overrun) = injected(plan, 40);
    let lost = 4000 - samples_of(&out, 12).len();
    assert_eq!(lost as u32, overrun);
    // Binomial(4000, 0.25): 1000 +- 27.4; five sigmas either way.
    assert!((863..=1137).contains(&lost), "{lost}");
    assert_eq!(
        injected(plan, 40).0,
        out,
        "the same seed fails the same reads"
    );
    let (other, _) = injected("seed=4\nspi-errors unit=2 from=0 to=40 rate=0.25", 40);
    assert_ne!(other, out);

    let plan = FaultPlan::parse(b"spi-errors unit=0 from=0 to=0.5 rate=1").unwrap();
    let clock = InjectionClock::new();
    let mut source = InjectingSource::new(Events(events(2).into_iter()), plan, &imus(), &clock);
    while let Some(e) = source.next_event().unwrap() {
        if e.t_us() > T0_US + 600_000 {
            break;
        }
    }
    assert!(source.imu_fault(), "a failed read is reported");
    assert!(!source.imu_fault(), "and reported once");
}

#[test]
fn pps_and_receiver_faults_remove_or_change_only_their_window() {
    let (out, _) = injected("pps-lost from=2 to=4\ngnss-absent from=5 to=6", 8);
    let pps: std::vec::Vec<u64> = out
        .iter()
        .filter(|e| matches!(e, SourceEvent::Pps(_)))
        .map(SourceEvent::t_us)
        .collect();
    assert_eq!(pps.len(), 6);
    assert!(pps.iter().all(|&t| !within(t, 2.0, 4.0)));
    let gnss = out
        .iter()
        .filter(|e| matches!(e, SourceEvent::Gnss(_)))
        .count();
    assert_eq!(gnss, 80 - 10);

    let (out, _) = injected("seed=9\ngnss-corrupt from=0 to=8 rate=0.01", 8);
    let (mut changed, mut bytes) = (0, 0);
    for e in &out {
        if let SourceEvent::Gnss(chunk) = e {
            bytes += chunk.bytes().len();
            changed += chunk.bytes().iter().filter(|&&b| b != 0x55).count();
        }
    }
    // Binomial(8000, 0.01): 80 +- 8.9.
    assert_eq!(bytes, 8000);
    assert!((40..=125).contains(&changed), "{changed}");
}

#[derive(Default)]
struct Frames(std::vec::Vec<u8>);

impl LogSink for Frames {
    type Error = ();
    fn write_frame(&mut self, frame: &[u8]) -> Result<Accepted, ()> {
        self.0.push(frame[0]);
        Ok(Accepted::Written)
    }
    fn flush(&mut self) -> Result<(), ()> {
        Ok(())
    }
}

#[test]
fn a_full_log_sink_drops_every_frame_while_the_fault_lasts() {
    let plan = FaultPlan::parse(b"log-full from=1 to=2").unwrap();
    let clock = InjectionClock::new();
    let mut source =
        InjectingSource::new(Events(events(3).into_iter()), plan.clone(), &imus(), &clock);
    let mut sink = InjectingSink::new(Frames::default(), &plan, &clock);
    let (mut written, mut dropped) = (0, 0);
    while let Some(e) = source.next_event().unwrap() {
        let full = within(e.t_us(), 1.0, 2.0);
        match sink.write_frame(&[1]).unwrap() {
            Accepted::Written => {
                written += 1;
                assert!(!full, "written at {}", e.t_us());
            }
            Accepted::Dropped => {
                dropped += 1;
                assert!(full, "dropped at {}", e.t_us());
            }
        }
    }
    assert_eq!(sink.inner_mut().0.len(), written);
    assert_eq!(dropped, 300 + 10 + 1);
}
