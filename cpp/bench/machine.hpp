// Benchmark-only probes of the machine: the core clock and the floating-point peak of one core,
// measured rather than taken from a data sheet (a virtual machine's nominal clock can be wrong).
// Both are timed in CPU time of the calling thread, so that other processes on a shared machine
// do not distort them (as long as they leave the caches alone).
#pragma once

#include <string>

namespace iwr::bench {

/// Core clock in GHz from a chain of dependent integer additions (one cycle each), timed for about
/// `seconds`. 0 where not implemented (only x86-64 with GCC or Clang).
double measure_clock_ghz(double seconds);

/// Throughput of one core in GFLOP/s for independent double-precision operations with registers of
/// `isa` ("sse2", "avx2" or "avx512"): separate multiplies and adds when fma is false (what the
/// kernel uses), fused multiply-adds (2 flops each) when true. Throws std::invalid_argument if the
/// CPU lacks the instruction set. Timed for about `seconds`.
double measure_peak_gflops(const std::string& isa, bool fma, double seconds);

/// Round trip of a cache line between two threads on two cores, in ns: one thread writes a
/// counter, the other answers on the same line, for about `seconds` of wall time; the least mean
/// over batches of 256 round trips (a batch the scheduler interrupted reads long). What each
/// hand-over and each row one core wrote and the other reads costs: on a virtual machine it
/// depends on where the host placed the vCPUs (the same die or not), and moves a DE generation's
/// own work on two threads (BENCHMARKS.md, twenty-ninth round). NaN when this thread may run on
/// fewer than two CPUs (its affinity), or when the second thread leaves a round trip unanswered
/// for a second (no core free for it).
/// Throws std::invalid_argument unless 0 <= seconds <= 3600.
double measure_core_round_trip_ns(double seconds);

}  // namespace iwr::bench
