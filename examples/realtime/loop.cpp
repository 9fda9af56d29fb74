// A 1 kHz control loop in C++ around the C generator that `seqmotion export-c` writes.
//
//   seqmotion export-c pancake build/c                               # build/c/seqmotion_{model,generator}.{h,c}
//   python examples/realtime/latent.py pancake build/latent.txt      # a motion's latent, start state and length
//   gcc -O2 -std=c99 -c build/c/seqmotion_model.c build/c/seqmotion_generator.c
//   g++ -O2 -std=c++17 -Ibuild/c examples/realtime/loop.cpp seqmotion_model.o seqmotion_generator.o -o loop
//   ./loop build/latent.txt 5000            # 5000 periods; as root (or with rtprio) it runs SCHED_FIFO
//
// Each period: sleep to an absolute deadline (clock_nanosleep, TIMER_ABSTIME: no drift), read the robot's state
// (here: the model's own dynamics, one sample of seqmotion_dynamics), call seqmotion_generator_step, apply the
// first output, then seqmotion_generator_prepare (the next call's work that no measurement changes, while the loop
// waits: the next call then holds one decoder step). No allocation, no lock, no system call but the sleep inside
// the loop. It prints the late wake-ups and the call's p50 / p99 / p99.9 / max.
#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <vector>

#include <pthread.h>
#include <sched.h>
#include <sys/mman.h>
#include <time.h>

#include "seqmotion_generator.h"

namespace {

constexpr long kPeriodNs = 1000000;  // 1 kHz
constexpr int kC = SEQMOTION_CHUNK, kS = SEQMOTION_STATE_DIM, kD = SEQMOTION_ACCEL_DIM;

long now_ns() {
    timespec t{};
    clock_gettime(CLOCK_MONOTONIC, &t);
    return t.tv_sec * 1000000000L + t.tv_nsec;
}

void sleep_until(long deadline_ns) {
    timespec t{deadline_ns / 1000000000L, deadline_ns % 1000000000L};
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &t, nullptr) == EINTR) {
    }
}

// The robot: the model's own dynamics, one sample (the chunk function, the other outputs zero: it is causal).
void robot(const double *x, const double *u, double *next) {
    static double accel[kC * kD], states[kC * kS];
    std::fill(accel, accel + kC * kD, 0.0);
    std::copy(u, u + kD, accel);
    seqmotion_dynamics(x, accel, seqmotion_physics_defaults, states);
    std::copy(states, states + kS, next);
}

double percentile(std::vector<long> v, double q) {
    std::sort(v.begin(), v.end());
    return v.empty() ? 0.0 : v[std::min(v.size() - 1, static_cast<size_t>(q * static_cast<double>(v.size())))] / 1e3;
}

}  // namespace

int main(int argc, char **argv) {
    if (argc < 2) {
        std::fprintf(stderr, "usage: %s LATENT_FILE [PERIODS]  (the file: K, then x0, then z, space separated)\n",
                     argv[0]);
        return 2;
    }
    const long periods = argc > 2 ? std::atol(argv[2]) : 5000;
    std::ifstream file(argv[1]);
    long length = 0;
    static float z[SEQMOTION_LATENT_DIM];
    double x0[kS];
    file >> length;
    for (double &v : x0) file >> v;
    for (float &v : z) file >> v;
    if (!file || periods < 1) {
        std::fprintf(stderr, "cannot read K, %d states and %d latent values from %s\n", kS, SEQMOTION_LATENT_DIM,
                     argv[1]);
        return 2;
    }

    // real time where permitted: memory locked, SCHED_FIFO (say so when not)
    if (mlockall(MCL_CURRENT | MCL_FUTURE) != 0) std::printf("mlockall: %s (memory not locked)\n", std::strerror(errno));
    sched_param param{};
    param.sched_priority = 80;
    const int fifo = pthread_setschedparam(pthread_self(), SCHED_FIFO, &param);
    std::printf("scheduling: %s\n", fifo == 0 ? "SCHED_FIFO 80" : "normal (SCHED_FIFO not permitted)");

    static seqmotion_generator gen;
    if (seqmotion_generator_start(&gen, z, x0, length, nullptr, 1) != 0) return 1;
    double out[kC * kD], x[kS], measured[kS];
    std::copy(x0, x0 + kS, x);
    int n = seqmotion_generator_step(&gen, nullptr, 0, out);  // the first chunk, before the loop
    std::vector<long> took, late;
    std::vector<long> prepared;
    prepared.reserve(periods);
    took.reserve(periods);
    late.reserve(periods);
    long start = now_ns() + kPeriodNs, overruns = 0;
    for (long i = 0; i < periods; ++i) {
        const long deadline = start + i * kPeriodNs;
        sleep_until(deadline);
        const long woke = now_ns();
        robot(x, out, x);  // the robot applied out[0] during the last period: its state now
        std::copy(x, x + kS, measured);
        const long begin = now_ns();
        n = seqmotion_generator_step(&gen, measured, 1, out);
        const long end = now_ns();
        if (n < 0) {
            std::fprintf(stderr, "seqmotion_generator_step: error %d\n", n);
            return 1;
        }
        // here the loop sends out[0] to the robot; then the next call's work that no measurement changes
        seqmotion_generator_prepare(&gen);
        prepared.push_back(now_ns() - end);
        took.push_back(end - begin);
        late.push_back(woke - deadline);
        if (end > deadline + kPeriodNs) ++overruns;
        if (gen.t - gen.origin > length + kC) {  // past the end and stopped: the next motion
            seqmotion_generator_reset(&gen);
            std::copy(x0, x0 + kS, x);
            seqmotion_generator_step(&gen, nullptr, 0, out);
        }
    }
    long late_count = std::count_if(late.begin(), late.end(), [](long v) { return v > 100000; });
    std::printf("%ld periods: %ld woke more than 100 us late, %ld overran\n", periods, late_count, overruns);
    std::printf("wake-up lateness: p50 %.1f  p99 %.1f  p99.9 %.1f  max %.1f us\n", percentile(late, 0.5),
                percentile(late, 0.99), percentile(late, 0.999), percentile(late, 1.0));
    std::printf("seqmotion_generator_step: p50 %.1f  p99 %.1f  p99.9 %.1f  max %.1f us\n", percentile(took, 0.5),
                percentile(took, 0.99), percentile(took, 0.999), percentile(took, 1.0));
    std::printf("seqmotion_generator_prepare (after the command): p50 %.1f  p99 %.1f  max %.1f us\n",
                percentile(prepared, 0.5), percentile(prepared, 0.99), percentile(prepared, 1.0));
    return 0;
}
