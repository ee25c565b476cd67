#!/usr/bin/env bash
# Cargo runner for thumbv7em-none-eabihf: runs a firmware ELF in QEMU's netduinoplus2 (an
# emulated STM32F405) and exits with the guest's semihosting exit code, so `cargo run`
# reports pass/fail. An ELF built for thumbv7m-none-eabi (a core without an FPU) runs in
# QEMU's netduino2 instead: an STM32F205, a Cortex-M3 with the F405's flash and SRAM
# addresses, so the one memory map serves both.
#
#   firmware/qemu-run.sh ELF [ARG...]
#
# ARGs reach the guest as its semihosting command line (the replay board reads its input
# and output paths there). QEMU joins them with spaces, so an ARG may not contain one.
# `-icount shift=0` makes the virtual clock advance 1 ns per instruction: SysTick then
# counts instructions, and runs are bit-identical.
#
# The guest's defmt log comes out on QEMU's stdout as binary defmt frames: piped through
# `defmt-print` when it is installed, otherwise saved to ELF.defmt. The guest's plain-text
# messages (run report, errors) come out on stderr.
# DYNACAL_QEMU_TIMEOUT (seconds, default 600) bounds a run so a hung guest fails.
set -euo pipefail

if [ $# -lt 1 ]; then
  echo "usage: $0 ELF [ARG...]" >&2
  exit 2
fi
elf="$1"
shift

if ! command -v qemu-system-arm >/dev/null 2>&1; then
  echo "qemu-run: qemu-system-arm not found; run scripts/setup" >&2
  exit 127
fi

semihosting="enable=on,target=native,arg=$(basename "$elf")"
for arg in "$@"; do
  case "$arg" in
    *" "*) echo "qemu-run: argument '$arg' contains a space, which semihosting cannot pass" >&2; exit 2 ;;
  esac
  # QEMU's option syntax escapes a comma by doubling it.
  semihosting+=",arg=${arg//,/,,}"
done

board=(-cpu cortex-m4 -machine netduinoplus2)
case "$elf" in
  */thumbv7m-none-eabi/*) board=(-cpu cortex-m3 -machine netduino2) ;;
esac
qemu=(timeout "${DYNACAL_QEMU_TIMEOUT:-600}"
  qemu-system-arm "${board[@]}" -nographic -monitor none
  -serial none -icount shift=0 -semihosting-config "$semihosting" -kernel "$elf")

if command -v defmt-print >/dev/null 2>&1; then
  set +e
  "${qemu[@]}" | defmt-print -e "$elf"
  status=${PIPESTATUS[0]}
  set -e
else
  set +e
  "${qemu[@]}" >"$elf.defmt"
  status=$?
  set -e
  echo "qemu-run: defmt log saved to $elf.defmt (install defmt-print to read it)" >&2
fi
if [ "$status" -eq 124 ]; then
  echo "qemu-run: guest did not exit within ${DYNACAL_QEMU_TIMEOUT:-600} s" >&2
fi
exit "$status"
