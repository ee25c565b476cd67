//! The real board: STM32F405 at 168 MHz, three ICM-42688-P IMUs on SPI1, GNSS PPS and the
//! IMUs' data-ready pulses captured by one 32-bit timer, log out of USART1.
//!
//! Timing: TIM2 free-runs at 1 MHz. Its four input-capture channels latch the counter on the
//! PPS edge (CH1, PA0) and on each IMU's data-ready pulse (CH2..CH4, PA1..PA3), so every
//! sample set and every PPS edge is stamped in hardware on one time base, independent of
//! when the software gets to it. The TIM2 interrupt takes each capture (and each wrap, every
//! 71.6 min, which extends the count to 64 bits) into a queue; the main loop sleeps (`wfi`)
//! until there is one, reads that IMU over SPI, and hands the event on. An over-capture
//! flag means a data-ready edge came before the previous capture was read: that sample set
//! is counted as overrun. Events are handed on 200 us after their stamp at the earliest,
//! in time order, so a capture whose interrupt waited behind another still comes first.
//!
//! GNSS: the u-blox receiver's UART on USART3 (RX PB11, 115 200 baud); its receive
//! interrupt queues the bytes with the timer's count at the last one, and the main loop
//! hands them on as GNSS chunks for the recorder's UBX parser.
//!
//! Watchdog: the independent watchdog resets the board if the main loop stops asking for
//! events for 500 ms (a hung SPI transfer, a loop gone wrong).
//!
//! Log: frames go into an 8 KiB queue drained by the USART1 transmit interrupt at
//! 921 600 baud; a frame that does not fit is dropped whole and counted (the recorder puts
//! the count in its Health frames). Defmt goes out over RTT to a debug probe.
//!
//! Pins: SPI1 SCK/MISO/MOSI = PA5/PA6/PA7, chip selects PC0/PC1/PC2 (IMU 0/1/2),
//! USART1 TX = PA9 (log), USART3 RX = PB11 (GNSS receiver).
//!
//! Model: the board model (`board-model.bin`) is read from flash sector 11 (`memory.x`); an
//! erased sector, or a blob that does not read, leaves the built-in model running, and the
//! reason goes out on RTT.
//!
//! This board needs hardware: CI builds it, nothing runs it (QEMU's netduinoplus2 models
//! neither TIM2 input capture nor the IMUs).

use core::cell::{Cell, RefCell};
use core::sync::atomic::{AtomicU32, Ordering};

use critical_section::Mutex;
use dynacal_core::board_model::{BoardModel, BoardModelError, MAX_BOARD_MODEL_LEN};
use dynacal_core::log::{Header, ImuConfig, ImuSampleSet, PpsEvent, MAX_IMUS, PROTOCOL_VERSION};
use dynacal_core::recorder::{
    Accepted, GnssChunk, LogSink, RecorderError, RecorderStats, SampleSource, SourceEvent,
};
use dynacal_core::replay::GNSS_CHUNK_MAX;
use embedded_hal::delay::DelayNs;
use embedded_hal_bus::spi::RefCellDevice;
use heapless::spsc::{Consumer, Producer, Queue};
use stm32f4xx_hal::gpio::{Output, Pin, PushPull};
use stm32f4xx_hal::pac::{self, interrupt, Interrupt, TIM2, USART1, USART3};
use stm32f4xx_hal::prelude::*;
use stm32f4xx_hal::rcc::{Clocks, Enable, Reset};
use stm32f4xx_hal::serial::{Config, Rx, Tx};
use stm32f4xx_hal::spi::{Mode, Phase, Polarity, Spi};
use stm32f4xx_hal::watchdog::IndependentWatchdog;

use super::icm42688::{self, Icm42688};
use crate::cost::Calibration;
// The defmt global logger: RTT, read by a debug probe.
use defmt_rtt as _;

/// Board name written in the log header.
pub const NAME: &str = "dynacal-stm32f405-3xicm42688";

/// The log queue: 8 KiB hold 89 ms of the UART's 92 KB/s against the log's 61 KB/s (three
/// IMUs at 1 kHz with the fusion's frames), and twice the largest burst (a round of 18
/// wavelet-variance frames, about 4 KB); a frame that does not fit is dropped and counted.
const LOG_QUEUE_LEN: usize = 8 * 1024;
/// Captures waiting for the main loop (4 channels at up to 1 kHz: 16 ms of them).
const CAPTURE_QUEUE_LEN: usize = 64;
/// Receiver bytes waiting for the main loop (a NAV-PVT frame is 100 bytes).
const GNSS_QUEUE_LEN: usize = 512;
const GNSS_BAUD: u32 = 115_200;
/// An event is handed on no sooner than this after its stamp, microseconds: longer than any
/// interrupt waits behind another, so events leave in the order of their stamps.
const REORDER_US: u64 = 200;
const WATCHDOG_MS: u32 = 500;
const LOG_BAUD: u32 = 921_600;
const TIMER_HZ: u32 = 1_000_000;

// TIM2_SR flag bits (RM0090): update, capture 1..4, trigger, over-capture 1..4.
const SR_UIF: u32 = 1 << 0;
const SR_CC1OF: u32 = 1 << 9;
const SR_CC2OF: u32 = 1 << 10;
const SR_CC3OF: u32 = 1 << 11;
const SR_CC4OF: u32 = 1 << 12;
const SR_FLAGS: u32 = 0b1_1110_0101_1111;

type ChipSelect<const N: u8> = Pin<'C', N, Output<PushPull>>;
type Bus = RefCell<Spi<pac::SPI1>>;
type Imu<const N: u8> =
    Icm42688<RefCellDevice<'static, Spi<pac::SPI1>, ChipSelect<N>, embedded_hal_bus::spi::NoDelay>>;

/// Bytes waiting for the USART1 transmit interrupt.
static LOG_TX: Mutex<RefCell<Option<Consumer<'static, u8>>>> = Mutex::new(RefCell::new(None));

/// One timer capture: channel 0 is the PPS, 1..=3 the IMUs' data-ready lines.
#[derive(Debug, Clone, Copy)]
struct Capture {
    channel: u8,
    t_us: u64,
}

/// The TIM2 interrupt's side of the capture queue.
static CAPTURES: Mutex<RefCell<Option<Producer<'static, Capture>>>> =
    Mutex::new(RefCell::new(None));
/// TIM2 wraps so far: the upper 32 bits of the 64-bit time.
static TIMER_HIGH: Mutex<Cell<u64>> = Mutex::new(Cell::new(0));
/// Captures lost: over-captured in the timer, or the queue full.
static CAPTURES_LOST: AtomicU32 = AtomicU32::new(0);
/// PPS edges lost (their pulse count still advances).
static PPS_LOST: AtomicU32 = AtomicU32::new(0);
/// The USART3 interrupt's side of the receiver's byte queue, and the time of its last byte.
static GNSS_RX: Mutex<RefCell<Option<Producer<'static, u8>>>> = Mutex::new(RefCell::new(None));
static GNSS_LAST_US: Mutex<Cell<u64>> = Mutex::new(Cell::new(0));

extern "C" {
    /// First byte of flash sector 11, where the board model is flashed (`memory.x`).
    static _board_model_start: u8;
}

/// The board model in flash, or the built-in one (with the reason, logged on RTT).
fn flash_model(imu_ids: &[u8]) -> BoardModel {
    // SAFETY: `_board_model_start` is the start of flash sector 11 (memory.x): mapped,
    // 128 KiB long (more than MAX_BOARD_MODEL_LEN), and never written while the board runs,
    // so reading it as bytes is sound.
    let blob = unsafe {
        core::slice::from_raw_parts(core::ptr::addr_of!(_board_model_start), MAX_BOARD_MODEL_LEN)
    };
    // An erased sector reads 0xFF: no model was flashed.
    let flashed = blob.iter().take(4).any(|&b| b != 0xFF);
    let (model, refused) = BoardModel::load_or_built_in(flashed.then_some(blob), imu_ids);
    match refused {
        Some(reason) => defmt::warn!(
            "board model in flash refused: {=str}; running the built-in model",
            reason_name(reason)
        ),
        None if flashed => defmt::info!("board model loaded from flash"),
        None => defmt::info!("no board model flashed: running the built-in model"),
    }
    model
}

fn reason_name(reason: BoardModelError) -> &'static str {
    match reason {
        BoardModelError::Truncated => "truncated",
        BoardModelError::BadMagic => "not a board model",
        BoardModelError::UnsupportedVersion(_) => "another version",
        BoardModelError::BadCrc => "damaged (CRC)",
        BoardModelError::Malformed => "malformed",
        BoardModelError::BufferTooSmall => "buffer too small",
        BoardModelError::Invalid { .. } => "values no filter can run",
    }
}

/// What `main` runs the recorder on.
pub struct Parts {
    /// The model the fusion runs.
    pub model: BoardModel,
    pub header: Header,
    pub source: CaptureSource,
    pub sink: UartSink,
}

/// Sets up clocks, the IMUs, the capture timer and the log UART. An IMU that does not
/// answer stops the board with a message on RTT (a logger with a missing IMU would record
/// a log that looks complete and is not).
pub fn init() -> Parts {
    let Some(dp) = pac::Peripherals::take() else {
        fatal("device peripherals taken twice")
    };
    let clocks = dp
        .RCC
        .constrain()
        .cfgr
        .use_hse(8.MHz())
        .sysclk(168.MHz())
        .pclk1(42.MHz())
        .pclk2(84.MHz())
        .freeze();
    let gpioa = dp.GPIOA.split();
    let gpioc = dp.GPIOC.split();

    let mut delay = BusyDelay::new(&clocks);
    let spi = Spi::new(
        dp.SPI1,
        (
            gpioa
                .pa5
                .into_alternate()
                .speed(stm32f4xx_hal::gpio::Speed::VeryHigh),
            gpioa
                .pa6
                .into_alternate()
                .speed(stm32f4xx_hal::gpio::Speed::VeryHigh),
            gpioa
                .pa7
                .into_alternate()
                .speed(stm32f4xx_hal::gpio::Speed::VeryHigh),
        ),
        Mode {
            polarity: Polarity::IdleHigh,
            phase: Phase::CaptureOnSecondTransition,
        },
        10.MHz(),
        &clocks,
    );
    let Some(bus) = cortex_m::singleton!(: Bus = RefCell::new(spi)) else {
        fatal("SPI bus taken twice")
    };
    let bus: &'static Bus = bus;
    let mut imu0: Imu<0> = Icm42688::new(device(bus, gpioc.pc0.into_push_pull_output()));
    let mut imu1: Imu<1> = Icm42688::new(device(bus, gpioc.pc1.into_push_pull_output()));
    let mut imu2: Imu<2> = Icm42688::new(device(bus, gpioc.pc2.into_push_pull_output()));
    for (k, result) in [
        imu0.init(&mut delay),
        imu1.init(&mut delay),
        imu2.init(&mut delay),
    ]
    .into_iter()
    .enumerate()
    {
        match result {
            Ok(()) => {}
            Err(icm42688::InitError::WrongDevice(id)) => {
                defmt::error!(
                    "IMU {=usize}: WHO_AM_I reads {=u8:#04x}, not an ICM-42688-P",
                    k,
                    id
                );
                fatal("IMU set-up failed")
            }
            Err(icm42688::InitError::Spi(_)) => {
                defmt::error!("IMU {=usize}: SPI transfer failed", k);
                fatal("IMU set-up failed")
            }
        }
    }

    // Capture inputs: PPS on TIM2_CH1, data-ready of IMU 0..2 on TIM2_CH2..CH4 (AF1).
    let _pps = gpioa.pa0.into_alternate::<1>();
    let _drdy0 = gpioa.pa1.into_alternate::<1>();
    let _drdy1 = gpioa.pa2.into_alternate::<1>();
    let _drdy2 = gpioa.pa3.into_alternate::<1>();
    let timer = start_capture_timer(dp.TIM2, &clocks);
    let Some(capture_queue) =
        cortex_m::singleton!(: Queue<Capture, CAPTURE_QUEUE_LEN> = Queue::new())
    else {
        fatal("capture queue taken twice")
    };
    let (capture_producer, captures) = capture_queue.split();
    critical_section::with(|cs| CAPTURES.borrow(cs).replace(Some(capture_producer)));

    // The receiver's UART: configured here, read by its interrupt.
    let gpiob = dp.GPIOB.split();
    let mut gnss_rx: Rx<USART3> = dp
        .USART3
        .rx(
            gpiob.pb11.into_alternate(),
            Config::default().baudrate(GNSS_BAUD.bps()),
            &clocks,
        )
        .unwrap_or_else(|_| fatal("USART3 configuration rejected"));
    let Some(gnss_queue) = cortex_m::singleton!(: Queue<u8, GNSS_QUEUE_LEN> = Queue::new()) else {
        fatal("receiver queue taken twice")
    };
    let (gnss_producer, gnss_bytes) = gnss_queue.split();
    critical_section::with(|cs| GNSS_RX.borrow(cs).replace(Some(gnss_producer)));
    gnss_rx.listen();
    // SAFETY: the handlers only touch their queues, the cells above and their own
    // peripheral's registers, all set up by now.
    unsafe {
        cortex_m::peripheral::NVIC::unmask(Interrupt::TIM2);
        cortex_m::peripheral::NVIC::unmask(Interrupt::USART3);
    }

    // Configured here; the transmit interrupt writes USART1's data register directly.
    let _tx: Tx<USART1> = dp
        .USART1
        .tx(
            gpioa.pa9.into_alternate(),
            Config::default().baudrate(LOG_BAUD.bps()),
            &clocks,
        )
        .unwrap_or_else(|_| fatal("USART1 configuration rejected"));
    let Some(queue) = cortex_m::singleton!(: Queue<u8, LOG_QUEUE_LEN> = Queue::new()) else {
        fatal("log queue taken twice")
    };
    let (producer, consumer) = queue.split();
    critical_section::with(|cs| LOG_TX.borrow(cs).replace(Some(consumer)));
    // SAFETY: the handler only touches LOG_TX and USART1, both ready by now.
    unsafe { cortex_m::peripheral::NVIC::unmask(Interrupt::USART1) };

    let mut imus = heapless::Vec::new();
    for imu_id in 0..MAX_IMUS as u8 {
        let mut model = heapless::String::new();
        let _ = model.push_str(icm42688::MODEL);
        let _ = imus.push(ImuConfig {
            imu_id,
            model,
            sample_rate_hz: icm42688::SAMPLE_RATE_HZ,
            gyro_scale_rad_s_per_count: icm42688::GYRO_SCALE_RAD_S_PER_COUNT,
            accel_scale_m_s2_per_count: icm42688::ACCEL_SCALE_M_S2_PER_COUNT,
        });
    }
    let mut board = heapless::String::new();
    let _ = board.push_str(NAME);
    let ids: heapless::Vec<u8, MAX_IMUS> = imus.iter().map(|i: &ImuConfig| i.imu_id).collect();
    Parts {
        model: flash_model(&ids),
        header: Header {
            protocol_version: PROTOCOL_VERSION,
            board,
            imus,
        },
        source: CaptureSource {
            timer,
            captures,
            gnss_bytes,
            imu0,
            imu1,
            imu2,
            pps_sequence: 0,
            overrun: 0,
            fault: false,
            temperature_deg_c: [f32::NAN; MAX_IMUS],
            watchdog: start_watchdog(dp.IWDG),
        },
        sink: UartSink { producer },
    }
}

fn device<const N: u8>(
    bus: &'static Bus,
    cs: ChipSelect<N>,
) -> RefCellDevice<'static, Spi<pac::SPI1>, ChipSelect<N>, embedded_hal_bus::spi::NoDelay> {
    match RefCellDevice::new_no_delay(bus, cs) {
        Ok(device) => device,
        Err(never) => match never {},
    }
}

/// TIM2 at 1 MHz, 32-bit free-running, channels 1..4 capturing rising edges of their own
/// inputs (TIx) through a short digital filter against ringing on the lines.
fn start_capture_timer(tim: TIM2, clocks: &Clocks) -> TIM2 {
    // SAFETY: TIM2 is owned here; enabling and resetting its clock touches only its bits.
    unsafe {
        TIM2::enable_unchecked();
        TIM2::reset_unchecked();
    }
    let prescaler = clocks.timclk1().raw() / TIMER_HZ - 1;
    tim.psc().write(|w| w.psc().set(prescaler as u16));
    tim.arr().write(|w| w.arr().set(u32::MAX));
    // CCxS = 01: channel x captures its own input TIx; ICxF = 0011: 8 samples at f_CK_INT.
    tim.ccmr1_input().write(|w| {
        w.cc1s().ti1();
        w.ic1f().set(0b0011);
        w.cc2s().ti2();
        w.ic2f().set(0b0011)
    });
    tim.ccmr2_input().write(|w| {
        w.cc3s().ti3();
        w.ic3f().set(0b0011);
        w.cc4s().ti4();
        w.ic4f().set(0b0011)
    });
    tim.ccer().write(|w| {
        w.cc1e().set_bit();
        w.cc2e().set_bit();
        w.cc3e().set_bit();
        w.cc4e().set_bit()
    });
    // Load the prescaler now rather than at the first wrap, then clear that update.
    tim.egr().write(|w| w.ug().set_bit());
    tim.sr().write(|w| unsafe { w.bits(0) });
    // Interrupts on every capture and on the wrap.
    tim.dier().write(|w| {
        w.uie().set_bit();
        w.cc1ie().set_bit();
        w.cc2ie().set_bit();
        w.cc3ie().set_bit();
        w.cc4ie().set_bit()
    });
    tim.cr1().modify(|_, w| w.cen().set_bit());
    tim
}

/// The independent watchdog, started: the main loop must feed it within [`WATCHDOG_MS`].
fn start_watchdog(iwdg: pac::IWDG) -> IndependentWatchdog {
    let mut watchdog = IndependentWatchdog::new(iwdg);
    watchdog.start(WATCHDOG_MS.millis());
    watchdog
}

#[interrupt]
fn TIM2() {
    // SAFETY: this handler is the only writer of TIM2's status register and reader of its
    // capture registers once the timer runs; the main loop only reads its counter.
    let tim = unsafe { &*TIM2::ptr() };
    let sr = tim.sr().read();
    let raw = sr.bits();
    let wrapped = sr.uif().bit_is_set();
    critical_section::with(|cs| {
        let high_cell = TIMER_HIGH.borrow(cs);
        let high = high_cell.get();
        // A capture taken just before a wrap seen in the same snapshot holds a large value;
        // one taken after holds a small value.
        let stamp = |capture: u32| -> u64 {
            let high = if wrapped && capture < 0x8000_0000 {
                high + 1
            } else {
                high
            };
            (high << 32) | u64::from(capture)
        };
        let mut queue = CAPTURES.borrow(cs).borrow_mut();
        let mut push = |channel: u8, capture: u32| {
            let event = Capture {
                channel,
                t_us: stamp(capture),
            };
            if queue.as_mut().is_none_or(|q| q.enqueue(event).is_err()) {
                CAPTURES_LOST.fetch_add(1, Ordering::Relaxed);
            }
        };
        // Reading a capture register clears its flag.
        if sr.cc1if().bit_is_set() {
            push(0, tim.ccr1().read().bits());
        }
        if sr.cc2if().bit_is_set() {
            push(1, tim.ccr2().read().bits());
        }
        if sr.cc3if().bit_is_set() {
            push(2, tim.ccr3().read().bits());
        }
        if sr.cc4if().bit_is_set() {
            push(3, tim.ccr4().read().bits());
        }
        if wrapped {
            high_cell.set(high + 1);
        }
    });
    let lost = [SR_CC2OF, SR_CC3OF, SR_CC4OF]
        .iter()
        .filter(|&&flag| raw & flag != 0)
        .count() as u32;
    CAPTURES_LOST.fetch_add(lost, Ordering::Relaxed);
    if raw & SR_CC1OF != 0 {
        PPS_LOST.fetch_add(1, Ordering::Relaxed);
    }
    // Status flags are rc_w0: clear only those seen set (the update and over-captures).
    let handled = raw & (SR_UIF | SR_CC1OF | SR_CC2OF | SR_CC3OF | SR_CC4OF);
    // SAFETY: only defined TIM2_SR flag bits are written.
    tim.sr().write(|w| unsafe { w.bits(SR_FLAGS & !handled) });
}

/// The timer's count now, extended to 64 bits, microseconds.
fn now_us() -> u64 {
    // SAFETY: reads of TIM2's counter and status; the TIM2 handler owns the writes.
    let tim = unsafe { &*TIM2::ptr() };
    critical_section::with(|cs| {
        let high = TIMER_HIGH.borrow(cs).get();
        let count = tim.cnt().read().bits();
        // A wrap not yet handled (interrupts are off here) shows as UIF with a small count.
        let pending_wrap = tim.sr().read().uif().bit_is_set() && count < 0x8000_0000;
        ((high + u64::from(pending_wrap)) << 32) | u64::from(count)
    })
}

#[interrupt]
fn USART3() {
    // SAFETY: this handler is the only reader of USART3's data register.
    let usart = unsafe { &*USART3::ptr() };
    let t_us = now_us();
    critical_section::with(|cs| {
        let mut rx = GNSS_RX.borrow(cs).borrow_mut();
        while usart.sr().read().rxne().bit_is_set() {
            let byte = usart.dr().read().dr().bits() as u8;
            // A full queue drops the byte: the receiver's parser finds the next frame.
            if let Some(q) = rx.as_mut() {
                let _ = q.enqueue(byte);
            }
        }
        GNSS_LAST_US.borrow(cs).set(t_us);
    });
}

/// Sample sets, PPS edges and receiver bytes, from the interrupts' queues.
pub struct CaptureSource {
    /// Owned so nothing else reconfigures it; the interrupt reads it.
    #[allow(dead_code)]
    timer: TIM2,
    captures: Consumer<'static, Capture>,
    gnss_bytes: Consumer<'static, u8>,
    imu0: Imu<0>,
    imu1: Imu<1>,
    imu2: Imu<2>,
    pps_sequence: u32,
    overrun: u32,
    fault: bool,
    temperature_deg_c: [f32; MAX_IMUS],
    watchdog: IndependentWatchdog,
}

impl CaptureSource {
    /// The next event whose stamp is at least [`REORDER_US`] old, earliest first: a
    /// capture (read from its IMU when it is a data-ready edge) or the receiver's bytes.
    fn ready_event(&mut self) -> Option<SourceEvent> {
        let now = now_us();
        let ripe = |t_us: u64| t_us.saturating_add(REORDER_US) <= now;
        let gnss_t_us = critical_section::with(|cs| GNSS_LAST_US.borrow(cs).get());
        let gnss_ready = self.gnss_bytes.ready() && ripe(gnss_t_us);
        match self.captures.peek().copied() {
            Some(c) if ripe(c.t_us) && !(gnss_ready && gnss_t_us < c.t_us) => {
                self.captures.dequeue();
                self.capture_event(c)
            }
            _ if gnss_ready => Some(self.gnss_chunk(gnss_t_us)),
            _ => None,
        }
    }

    /// A capture as an event: a PPS edge, or the sample set its IMU has ready.
    fn capture_event(&mut self, capture: Capture) -> Option<SourceEvent> {
        if capture.channel == 0 {
            let lost = PPS_LOST.swap(0, Ordering::Relaxed);
            // A PPS edge lost to over-capture still advances the pulse count, so the gap
            // shows in the logged sequence numbers.
            self.pps_sequence = self.pps_sequence.wrapping_add(lost);
            let event = SourceEvent::Pps(PpsEvent {
                t_us: capture.t_us,
                sequence: self.pps_sequence,
            });
            self.pps_sequence = self.pps_sequence.wrapping_add(1);
            return Some(event);
        }
        let imu_id = capture.channel - 1;
        let read = match imu_id {
            0 => self.imu0.read_sample().map_err(|_| ()),
            1 => self.imu1.read_sample().map_err(|_| ()),
            _ => self.imu2.read_sample().map_err(|_| ()),
        };
        match read {
            Ok(raw) => {
                self.temperature_deg_c[usize::from(imu_id)] = raw.temperature_deg_c();
                Some(SourceEvent::Imu(ImuSampleSet {
                    t_us: capture.t_us,
                    imu_id,
                    gyro_counts: raw.gyro_counts.map(i32::from),
                    accel_counts: raw.accel_counts.map(i32::from),
                }))
            }
            Err(()) => {
                self.fault = true;
                self.overrun += 1;
                None
            }
        }
    }

    /// Up to a chunk of the receiver's bytes, stamped with the last byte's time.
    fn gnss_chunk(&mut self, t_us: u64) -> SourceEvent {
        let mut data = [0u8; GNSS_CHUNK_MAX];
        let mut len = 0;
        while len < GNSS_CHUNK_MAX {
            let Some(byte) = self.gnss_bytes.dequeue() else {
                break;
            };
            data[len] = byte;
            len += 1;
        }
        SourceEvent::Gnss(GnssChunk {
            t_us,
            len: len as u8,
            data,
        })
    }
}

impl SampleSource for CaptureSource {
    type Error = core::convert::Infallible;

    /// Sleeps until an event is ready; feeds the watchdog each time it wakes.
    fn next_event(&mut self) -> Result<Option<SourceEvent>, Self::Error> {
        loop {
            self.watchdog.feed();
            if let Some(event) = self.ready_event() {
                return Ok(Some(event));
            }
            if !self.captures.ready() && !self.gnss_bytes.ready() {
                cortex_m::asm::wfi();
            }
        }
    }

    fn samples_overrun(&self) -> u32 {
        self.overrun
            .saturating_add(CAPTURES_LOST.load(Ordering::Relaxed))
    }

    fn imu_fault(&mut self) -> bool {
        core::mem::take(&mut self.fault)
    }

    fn imu_temperatures_deg_c(&mut self) -> [f32; MAX_IMUS] {
        self.temperature_deg_c
    }
}

/// The log queue feeding the USART1 transmit interrupt.
pub struct UartSink {
    producer: Producer<'static, u8>,
}

impl LogSink for UartSink {
    type Error = core::convert::Infallible;

    fn write_frame(&mut self, frame: &[u8]) -> Result<Accepted, Self::Error> {
        // Whole frames only: a cut frame would corrupt the next one on the wire too.
        if self.producer.capacity() - self.producer.len() < frame.len() {
            return Ok(Accepted::Dropped);
        }
        for &byte in frame {
            let _ = self.producer.enqueue(byte);
        }
        // SAFETY: setting TXEIE is a single read-modify-write of USART1's own register;
        // the handler clears it when the queue runs dry.
        unsafe { (*USART1::ptr()).cr1().modify(|_, w| w.txeie().set_bit()) };
        Ok(Accepted::Written)
    }

    fn flush(&mut self) -> Result<(), Self::Error> {
        while !self.producer.is_empty() {
            cortex_m::asm::nop();
        }
        Ok(())
    }
}

#[interrupt]
fn USART1() {
    // SAFETY: this handler is the only writer of USART1's data register.
    let usart = unsafe { &*USART1::ptr() };
    critical_section::with(|cs| {
        let mut tx = LOG_TX.borrow(cs).borrow_mut();
        let Some(consumer) = tx.as_mut() else {
            usart.cr1().modify(|_, w| w.txeie().clear_bit());
            return;
        };
        while usart.sr().read().txe().bit_is_set() {
            match consumer.dequeue() {
                Some(byte) => usart.dr().write(|w| w.dr().set(byte as u16)),
                None => {
                    usart.cr1().modify(|_, w| w.txeie().clear_bit());
                    break;
                }
            }
        }
    });
}

/// Millisecond waits during start-up, by counting core cycles (SysTick belongs to the cost
/// clock).
struct BusyDelay {
    cycles_per_us: u32,
}

impl BusyDelay {
    fn new(clocks: &Clocks) -> Self {
        BusyDelay {
            cycles_per_us: clocks.sysclk().raw() / 1_000_000,
        }
    }
}

impl DelayNs for BusyDelay {
    fn delay_ns(&mut self, ns: u32) {
        cortex_m::asm::delay((ns / 1000 + 1).saturating_mul(self.cycles_per_us));
    }
}

/// A live board never ends its source; the recorder returns only on an error, after which
/// the board reports it and restarts so logging resumes.
pub fn finish(
    result: Result<
        RecorderStats,
        RecorderError<core::convert::Infallible, core::convert::Infallible>,
    >,
    calibration: &Calibration,
    sink: &mut UartSink,
) -> ! {
    let _ = sink.flush();
    defmt::info!(
        "stack at the deepest {=usize} bytes, statics {=usize} bytes",
        crate::stack::peak_bytes(),
        crate::stack::static_bytes()
    );
    match result {
        Ok(stats) => defmt::warn!(
            "source ended after {=u64} sample sets ({=u64} core cycles of recording, \
             {=u64} in the calibration loop's {=u64} instructions); restarting",
            stats.total_imu_sample_sets(),
            stats.record_ticks,
            calibration.ticks,
            calibration.instructions
        ),
        Err(RecorderError::UnknownImu { imu_id, t_us }) => {
            defmt::error!(
                "sample from undeclared IMU {=u8} at {=u64} us",
                imu_id,
                t_us
            )
        }
        Err(RecorderError::TimeWentBackwards {
            t_us,
            previous_t_us,
        }) => defmt::error!(
            "capture time went backwards: {=u64} us after {=u64} us",
            t_us,
            previous_t_us
        ),
        Err(RecorderError::Encode(_)) => defmt::error!("log encoding failed"),
        Err(RecorderError::Source(never)) | Err(RecorderError::Sink(never)) => match never {},
    }
    cortex_m::peripheral::SCB::sys_reset()
}

pub fn fatal(what: &str) -> ! {
    defmt::error!("fatal: {=str}; restarting", what);
    cortex_m::peripheral::SCB::sys_reset()
}

/// Logs where the panic was and its message when the message is a plain string. A message
/// with arguments is not formatted: `core::fmt` would cost 3 KB of the 128 KiB of flash
/// the image must fit in, and the file and line find the place.
pub fn fatal_panic(info: &core::panic::PanicInfo) -> ! {
    let (file, line) = info.location().map_or(("?", 0), |l| (l.file(), l.line()));
    let message = info.message().as_str().unwrap_or("(a formatted message)");
    defmt::error!("panic at {=str}:{=u32}: {=str}", file, line, message);
    cortex_m::peripheral::SCB::sys_reset()
}

pub fn fatal_hard_fault(pc: u32) -> ! {
    defmt::error!("HardFault at pc={=u32:#010x}; restarting", pc);
    cortex_m::peripheral::SCB::sys_reset()
}
