//! The real board: STM32F405 at 168 MHz, three ICM-42688-P IMUs on SPI1, GNSS PPS and the
//! IMUs' data-ready pulses captured by one 32-bit timer, log out of USART1.
//!
//! Timing: TIM2 free-runs at 1 MHz. Its four input-capture channels latch the counter on the
//! PPS edge (CH1, PA0) and on each IMU's data-ready pulse (CH2..CH4, PA1..PA3), so every
//! sample set and every PPS edge is stamped in hardware on one time base, independent of
//! when the software gets to it. The 32-bit capture is extended to 64 bits by counting
//! timer wraps (every 71.6 min). An over-capture flag means a data-ready edge came before
//! the previous capture was read: that sample set is counted as overrun.
//!
//! Log: frames go into a 16 KiB queue drained by the USART1 transmit interrupt at
//! 921 600 baud; a frame that does not fit is dropped whole and counted (the recorder puts
//! the count in its Health frames). Defmt goes out over RTT to a debug probe.
//!
//! Pins: SPI1 SCK/MISO/MOSI = PA5/PA6/PA7, chip selects PC0/PC1/PC2 (IMU 0/1/2),
//! USART1 TX = PA9.
//!
//! Model: the board model (`board-model.bin`) is read from flash sector 11 (`memory.x`); an
//! erased sector, or a blob that does not read, leaves the built-in model running, and the
//! reason goes out on RTT.
//!
//! This board needs hardware: CI builds it, nothing runs it (QEMU's netduinoplus2 models
//! neither TIM2 input capture nor the IMUs).

use core::cell::RefCell;

use critical_section::Mutex;
use dynacal_core::board_model::{BoardModel, BoardModelError, MAX_BOARD_MODEL_LEN};
use dynacal_core::log::{Header, ImuConfig, ImuSampleSet, PpsEvent, MAX_IMUS, PROTOCOL_VERSION};
use dynacal_core::recorder::{
    Accepted, LogSink, RecorderError, RecorderStats, SampleSource, SourceEvent,
};
use embedded_hal::delay::DelayNs;
use embedded_hal_bus::spi::RefCellDevice;
use heapless::spsc::{Consumer, Producer, Queue};
use stm32f4xx_hal::gpio::{Output, Pin, PushPull};
use stm32f4xx_hal::pac::{self, interrupt, Interrupt, TIM2, USART1};
use stm32f4xx_hal::prelude::*;
use stm32f4xx_hal::rcc::{Clocks, Enable, Reset};
use stm32f4xx_hal::serial::{Config, Tx};
use stm32f4xx_hal::spi::{Mode, Phase, Polarity, Spi};

use super::icm42688::{self, Icm42688};
use crate::cost::Calibration;
// The defmt global logger: RTT, read by a debug probe.
use defmt_rtt as _;

/// Board name written in the log header.
pub const NAME: &str = "dynacal-stm32f405-3xicm42688";

const LOG_QUEUE_LEN: usize = 16 * 1024;
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
            high: 0,
            imu0,
            imu1,
            imu2,
            pending: heapless::Vec::new(),
            pps_sequence: 0,
            overrun: 0,
            fault: false,
            temperature_deg_c: [f32::NAN; MAX_IMUS],
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
    tim.cr1().modify(|_, w| w.cen().set_bit());
    tim
}

/// Sample sets and PPS edges, stamped by TIM2 captures.
pub struct CaptureSource {
    timer: TIM2,
    /// Timer wraps so far: the upper 32 bits of the 64-bit time.
    high: u64,
    imu0: Imu<0>,
    imu1: Imu<1>,
    imu2: Imu<2>,
    /// Events captured together, handed out in time order.
    pending: heapless::Vec<SourceEvent, 4>,
    pps_sequence: u32,
    overrun: u32,
    fault: bool,
    temperature_deg_c: [f32; MAX_IMUS],
}

impl CaptureSource {
    /// Waits for at least one capture and reads everything that is ready.
    fn poll(&mut self) {
        while self.pending.is_empty() {
            let sr = self.timer.sr().read();
            let wrapped = sr.uif().bit_is_set();
            // A capture taken just before a wrap that is seen in the same snapshot holds a
            // large value; one taken after holds a small value.
            let stamp = |high: u64, capture: u32| -> u64 {
                let high = if wrapped && capture < 0x8000_0000 {
                    high + 1
                } else {
                    high
                };
                (high << 32) | capture as u64
            };
            let raw = sr.bits();
            // Flags this snapshot handles: the update (wrap) and the over-captures. Status
            // flags are rc_w0, so writing 1 leaves a flag alone and 0 clears it; only the
            // flags seen set are cleared, so one raised since the read is kept for the next
            // pass. Reading a CCR below clears its CCxIF.
            let handled = raw & (SR_UIF | SR_CC1OF | SR_CC2OF | SR_CC3OF | SR_CC4OF);
            // SAFETY: only defined TIM2_SR flag bits are written.
            self.timer
                .sr()
                .write(|w| unsafe { w.bits(SR_FLAGS & !handled) });
            // An over-captured data-ready line lost one sample set of that IMU.
            self.overrun += [SR_CC2OF, SR_CC3OF, SR_CC4OF]
                .iter()
                .filter(|&&flag| raw & flag != 0)
                .count() as u32;
            // A PPS edge lost to over-capture still advances the pulse count, so the gap
            // shows in the logged sequence numbers.
            if raw & SR_CC1OF != 0 {
                self.pps_sequence = self.pps_sequence.wrapping_add(1);
            }
            if sr.cc1if().bit_is_set() {
                let t_us = stamp(self.high, self.timer.ccr1().read().bits());
                let _ = self.pending.push(SourceEvent::Pps(PpsEvent {
                    t_us,
                    sequence: self.pps_sequence,
                }));
                self.pps_sequence = self.pps_sequence.wrapping_add(1);
            }
            let ready = [
                sr.cc2if().bit_is_set(),
                sr.cc3if().bit_is_set(),
                sr.cc4if().bit_is_set(),
            ];
            for (imu_id, ready) in ready.into_iter().enumerate() {
                if !ready {
                    continue;
                }
                let capture = match imu_id {
                    0 => self.timer.ccr2().read().bits(),
                    1 => self.timer.ccr3().read().bits(),
                    _ => self.timer.ccr4().read().bits(),
                };
                let t_us = stamp(self.high, capture);
                let read = match imu_id {
                    0 => self.imu0.read_sample().map_err(|_| ()),
                    1 => self.imu1.read_sample().map_err(|_| ()),
                    _ => self.imu2.read_sample().map_err(|_| ()),
                };
                match read {
                    Ok(raw) => {
                        self.fault = false;
                        self.temperature_deg_c[imu_id] = raw.temperature_deg_c();
                        let _ = self.pending.push(SourceEvent::Imu(ImuSampleSet {
                            t_us,
                            imu_id: imu_id as u8,
                            gyro_counts: raw.gyro_counts.map(i32::from),
                            accel_counts: raw.accel_counts.map(i32::from),
                        }));
                    }
                    Err(()) => {
                        self.fault = true;
                        self.overrun += 1;
                    }
                }
            }
            if wrapped {
                self.high += 1;
            }
        }
    }
}

impl SampleSource for CaptureSource {
    type Error = core::convert::Infallible;

    fn next_event(&mut self) -> Result<Option<SourceEvent>, Self::Error> {
        self.poll();
        let earliest = self
            .pending
            .iter()
            .enumerate()
            .min_by_key(|(_, e)| e.t_us())
            .map(|(k, _)| k);
        Ok(earliest.map(|k| self.pending.swap_remove(k)))
    }

    fn samples_overrun(&self) -> u32 {
        self.overrun
    }

    fn imu_fault(&self) -> bool {
        self.fault
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

pub fn fatal_panic(info: &core::panic::PanicInfo) -> ! {
    defmt::error!("panic: {}", defmt::Display2Format(info));
    cortex_m::peripheral::SCB::sys_reset()
}

pub fn fatal_hard_fault(pc: u32) -> ! {
    defmt::error!("HardFault at pc={=u32:#010x}; restarting", pc);
    cortex_m::peripheral::SCB::sys_reset()
}
