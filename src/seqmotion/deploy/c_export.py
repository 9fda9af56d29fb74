"""``seqmotion export-c MODEL OUT/``: a trained model's decoder step and its task's dynamics as dependency-free C99.

    seqmotion export-c pancake pancake-c/            # pancake-c/seqmotion_model.{h,c}, seqmotion_generator.{h,c}
    gcc -O2 -std=c99 -c pancake-c/*.c                # no library, no heap: C99 and <math.h>

``export_c(model, OUT)`` writes, with ``prefix`` (default ``seqmotion``) on every name:

* ``PREFIX_model.h`` / ``PREFIX_model.c`` — the graphs of the ONNX export (:mod:`seqmotion.deploy.export`: the
  same traced decoder step, dynamics, ``outputs_for`` and constraint) compiled to C for one trajectory, shapes fixed:
  ``PREFIX_decoder_step(h, c, window, h_out, c_out, accel)`` (float; ``h``, ``c``: L·H, layer-major; ``window``:
  C states; ``accel``: the next C outputs), ``PREFIX_dynamics(x, accel, physics, states)`` (double: the C states
  that C outputs give from ``x``), where the task has them ``PREFIX_outputs_for(x, accel, physics, outputs)`` and
  ``PREFIX_violation(states, accel, violation)`` (C + 1 states, C outputs → C violations). The contract's
  constants are ``#define``\\ s of the header (C, the layouts' sizes, dt, L, H, the stop's τ, limits and factors) and
  arrays (the physics' defaults and names, the velocity columns). Dynamics the contract names a closed form of (the
  double integrator: pancake, tray) are that closed form in C, as in the NumPy runner.
* ``PREFIX_generator.h`` / ``PREFIX_generator.c`` — the online generator on those functions
  (:data:`GENERATOR_C`): ``PREFIX_generator_start(g, z, x0, length, physics)``, then ``n = PREFIX_generator_step(g,
  measured, out)`` with the stepper's contract (``stepper.py``: the chunk boundary, the replanning correction
  between boundaries, the stop past the end), and ``PREFIX_rollout`` (``generate`` from a latent).

Every function works on the caller's arrays and the file's own static arrays: no heap, no recursion, a fixed
number of operations per call. The static arrays make them not reentrant: call one model's functions from one
thread (or compile the source once per thread with another prefix).

The graphs become C through :mod:`seqmotion.deploy.c_emit` (our own emitter, and why not an existing one).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .c_emit import Emitter
from .c_values import F32, F64, I32, Statics, literal

# --- a model's C source ---------------------------------------------------------------------------------------

TANH_F = """\
static inline float tanh_f(float x)
{
    /* tanh of a float through one expf: glibc's tanhf goes through expm1f, five times an expf (and the LSTM
     * cells call it 4 H times a step); absolute error below 1e-7, like the float32 it is computed in */
    const float e = expf(-2.0f * fabsf(x));
    const float t = (1.0f - e) / (1.0f + e);
    return x < 0.0f ? -t : t;
}"""

DOUBLE_INTEGRATOR_C = """\
void {p}_dynamics(const double *restrict x, const double *restrict accel, const double *restrict physics,
                  double *restrict states)
{{
    /* the double integrator in closed form (numpy_physics.integrate: the same sums in the same order) */
    double s1[{d}] = {{0}}, s2[{d}] = {{0}};
    (void)physics;
    for (int k = 0; k < {c}; ++k) {{
        const double n_dt = (double)(k + 1) * {dt};
        for (int i = 0; i < {d}; ++i) {{
            s2[i] += s1[i];
            s1[i] += accel[k * {d} + i];
            states[k * {s} + i] = x[i] + n_dt * x[{d} + i] + {dt2} * (s2[i] + 0.5 * s1[i]);
            states[k * {s} + {d} + i] = x[{d} + i] + {dt} * s1[i];
        }}
    }}
}}
"""

MODEL_H = """\
/* {p}_model.h: the {task!r} model ({source}) as C99, written by seqmotion export-c; re-export rather than edit.
 *
 * One trajectory, shapes fixed; every array is the caller's (row-major, no padding); outputs must not overlap
 * inputs. No heap, no recursion; the functions use static arrays of their own, so they are not reentrant: call
 * them from one thread.
 *
 *   {p}_decoder_step: h, c (L*H floats, layer-major: layer l's cells at l*H) and window (C states) -> h_out,
 *       c_out and accel (the next C outputs). The first step of a motion reads c = z (the latent), h = 0 and x0
 *       repeated C times (see {p}_generator.h).
 *   {p}_dynamics: x (S) and accel (C outputs) at physics (P values, {physics_doc}) -> states (the C states
 *       that follow x).
{extra_doc} *
 * States ({state_kind}): {states}.
 * Outputs ({accel_kind}): {accels}.
 */
#ifndef {P}_MODEL_H
#define {P}_MODEL_H

#ifdef __cplusplus
extern "C" {{
#endif

#define {P}_CHUNK {c}                       /* C: outputs per decoder step */
#define {P}_STATE_DIM {s}                   /* S */
#define {P}_ACCEL_DIM {d}                   /* d: outputs per sample */
#define {P}_INPUT_DIM {input_dim}           /* columns of a motion the encoder reads */
#define {P}_LAYERS {layers}                 /* L */
#define {P}_HIDDEN {hidden}                 /* H */
#define {P}_LATENT_DIM {latent}             /* L*H */
#define {P}_PHYSICS_DIM {physics_dim}       /* P: physics values the dynamics read */
#define {P}_DT {dt}                         /* s per sample */
#define {P}_DEFAULT_LENGTH {default_length}  /* K of the longest trained motion (0: none) */
#define {P}_CONSTRAINT {constraint}          /* 1: {p}_violation exists */
#define {P}_STOP_OUTPUTS {stop_outputs}      /* the stop's outputs: 0 none (hold 0), 1 accelerations, 2 outputs_for */
#define {P}_HAS_VELOCITY {has_velocity}       /* 1: {p}_velocity_columns name the velocity of each output */
#define {P}_STOP_TAU {tau}
#define {P}_STOP_SHRINK_COUNT {shrink_count}
#define {P}_REST_VELOCITY {rest}
#define {P}_VIOLATION_TOLERANCE {tolerance}
#define {P}_MAX_ABS_STATE 1e6               /* a measured state beyond this is refused (a sensor fault) */

extern const double {p}_stop_shrink[{shrink_count}];
extern const double {p}_stop_accel_limit[{d}];   /* per velocity column, its unit per second */
extern const int {p}_velocity_columns[{d}];
extern const double {p}_physics_defaults[{physics_len}];   /* the contract's values, {physics_doc} */
extern const char *const {p}_physics_names[{physics_len}];
extern const char *const {p}_state_names[{s}];
extern const char *const {p}_accel_names[{d}];

{declarations}

#ifdef __cplusplus
}}
#endif

#endif
"""

GENERATOR_H = """\
/* {p}_generator.h: the online motion generator of the {task!r} model, written by seqmotion export-c.
 *
 * The stepper's contract (seqmotion/core/stepper.py), for one motion:
 *   {p}_generator_start(&g, z, x0, length, physics, replan);   z: L*H floats; physics: NULL for the defaults
 *   n = {p}_generator_step(&g, NULL, 0, out);                  first call: out[0..C-1], the first chunk
 *   n = {p}_generator_step(&g, measured, m, out);              later: the m >= 1 states measured since (at
 *                                                              most as many as the last call returned)
 *   {p}_generator_prepare(&g);                                 optional, once the command went out: the next
 *                                                              call's work that no measurement changes
 * Each call writes n outputs (1..C, n*d doubles) into out, from the sample after the latest measured state to
 * the end of its chunk: at a chunk boundary one decoder step on the chunk just measured; between boundaries
 * (replan) the plan corrected by the decoder's response to what was measured against what the plan predicted
 * (two decoder steps: the predicted window's one is what {p}_generator_prepare makes ahead of the call, so a call
 * after it holds one; the outputs are the same either way); from sample
 * K-1 on, the stop (a deceleration of the velocity columns within the contract's limits that keeps the
 * constraint, then a hold). A negative n is an error and changes nothing: {P}_ERR_*.
 * {p}_rollout: generate, the decoder in closed loop through the dynamics, from a latent (what PyTorch's
 * decode computes): states (length*S) and outputs ((length-1)*d).
 * Not reentrant (the model's functions use static arrays): one thread.
 */
#ifndef {P}_GENERATOR_H
#define {P}_GENERATOR_H

#include "{p}_model.h"

#ifdef __cplusplus
extern "C" {{
#endif

#define {P}_ERR_CALL (-1)       /* states on the first call, or none on a later one */
#define {P}_ERR_TOO_MANY (-2)   /* more states than the last call returned outputs */
#define {P}_ERR_STATE (-3)      /* a measured state with NaN, inf or a magnitude above {P}_MAX_ABS_STATE */
#define {P}_ERR_NAN (-4)        /* the outputs came out NaN: check the measurements, then start again */
#define {P}_ERR_ARGUMENT (-5)   /* start: length < 2, or a latent or x0 not finite */

typedef struct {p}_generator {{
    float z[{P}_LATENT_DIM];
    float h[{P}_LATENT_DIM], c[{P}_LATENT_DIM];            /* the decoder state at the chunk's boundary */
    float h_next[{P}_LATENT_DIM], c_next[{P}_LATENT_DIM];  /* after the chunk's step */
    float h_scratch[{P}_LATENT_DIM], c_scratch[{P}_LATENT_DIM];
    float window_m[{P}_CHUNK * {P}_STATE_DIM], mean_m[{P}_CHUNK * {P}_ACCEL_DIM];  /* the measured window's step */
    float window_p[{P}_CHUNK * {P}_STATE_DIM], mean_p[{P}_CHUNK * {P}_ACCEL_DIM];  /* the predicted window's */
    float window_f[{P}_CHUNK * {P}_STATE_DIM];
    float mean_f[{P}_CHUNK * {P}_ACCEL_DIM];
    double window[{P}_CHUNK * {P}_STATE_DIM];    /* the chunk's decoder window */
    double measured[{P}_CHUNK * {P}_STATE_DIM];  /* the states measured in the chunk */
    double plan[{P}_CHUNK * {P}_ACCEL_DIM];      /* the chunk's outputs as planned */
    double pred[{P}_CHUNK * {P}_STATE_DIM];      /* the states the plan predicts */
    double latest[{P}_STATE_DIM], x0[{P}_STATE_DIM];
    double physics[{physics_len}];
    double cand[{P}_STOP_SHRINK_COUNT + 1][{P}_CHUNK * {P}_ACCEL_DIM];   /* the stop's candidates */
    double pad[{P}_CHUNK * {P}_ACCEL_DIM], states[{P}_CHUNK * {P}_STATE_DIM], start[{P}_STATE_DIM];
    float v_states[({P}_CHUNK + 1) * {P}_STATE_DIM], v_accel[{P}_CHUNK * {P}_ACCEL_DIM], v_out[{P}_CHUNK];
    long t, origin, length;
    int available, started, planned, replan;
    int prepared;  /* the position whose predicted window's step is in mean_p (-1: none) */
}} {p}_generator;

int {p}_generator_start({p}_generator *g, const float *z, const double *x0, long length, const double *physics,
                        int replan);
void {p}_generator_reset({p}_generator *g);
unsigned long {p}_generator_size(void);  /* sizeof({p}_generator), for a caller that allocates it by size */
int {p}_generator_step({p}_generator *g, const double *measured, int count, double *out);
void {p}_generator_prepare({p}_generator *g);
int {p}_rollout(const float *z, const double *x0, long length, const double *physics, double *states,
                double *accel);

#ifdef __cplusplus
}}
#endif

#endif
"""

GENERATOR_C = """\
/* {p}_generator.c: the online motion generator on {p}_model.c, written by seqmotion export-c (module
 * seqmotion/deploy/c_export.py); the same algorithm as seqmotion/core/stepper.py's StepperCore for one motion. */
#include <math.h>
#include <string.h>

#include "{p}_generator.h"

#define CH {P}_CHUNK
#define SD {P}_STATE_DIM
#define AD {P}_ACCEL_DIM
#define NS {P}_STOP_SHRINK_COUNT

static int usable(const double *x, int n)
{{
    for (int i = 0; i < n; ++i)
        if (!(fabs(x[i]) <= {P}_MAX_ABS_STATE)) return 0; /* NaN and inf fail it too */
    return 1;
}}

static void decode(const float *h, const float *c, const double *rows_a, int count_a, const double *rows_b,
                   float *h_out, float *c_out, float *window, float *mean)
{{
    /* one decoder step on the window rows_a[0..count_a) then rows_b (C states in all) */
    for (int i = 0; i < count_a * SD; ++i) window[i] = (float)rows_a[i];
    for (int i = count_a * SD; i < CH * SD; ++i) window[i] = (float)rows_b[i - count_a * SD];
    {p}_decoder_step(h, c, window, h_out, c_out, mean);
}}

int {p}_generator_start({p}_generator *g, const float *z, const double *x0, long length, const double *physics,
                        int replan)
{{
    if (length < 2 || !usable(x0, SD)) return {P}_ERR_ARGUMENT;
    for (int i = 0; i < {P}_LATENT_DIM; ++i)
        if (!isfinite(z[i])) return {P}_ERR_ARGUMENT;
    memcpy(g->z, z, sizeof g->z);
    memcpy(g->x0, x0, sizeof g->x0);
    for (int i = 0; i < {physics_len}; ++i) g->physics[i] = physics ? physics[i] : {p}_physics_defaults[i];
    g->length = length;
    g->replan = replan != 0;
    {p}_generator_reset(g);
    return 0;
}}

unsigned long {p}_generator_size(void)
{{
    return (unsigned long)sizeof({p}_generator);
}}

void {p}_generator_reset({p}_generator *g)
{{
    g->t = g->origin = 0;
    g->started = g->available = g->planned = 0;
    g->prepared = -1;
    memcpy(g->latest, g->x0, sizeof g->latest);
    memset(g->h_next, 0, sizeof g->h_next);  /* h = 0, c = z */
    memcpy(g->c_next, g->z, sizeof g->c_next);
    memset(g->measured, 0, sizeof g->measured);
}}

static void predict({p}_generator *g, const double *x, const double *outputs, int n, double *states)
{{
    /* the states that n outputs give from x, through the dynamics' chunk padded with zeros (it is causal) */
    memset(g->pad, 0, sizeof g->pad);
    memcpy(g->pad, outputs, (size_t)n * AD * sizeof(double));
    {p}_dynamics(x, g->pad, g->physics, states);
}}

#if {P}_HAS_VELOCITY
static void stop_accel(const double *v, int n, double scale, double *a)
{{
    /* core/stepper.py's stop_accel for one factor: clip(-scale v / tau, +-limit), 0 once every |v| <= rest */
    const double rate = scale / {P}_STOP_TAU;
    double speed[AD], sign[AD], steps[AD], v_m[AD];
    int still = 0;
    for (int i = 0; i < AD; ++i) {{
        const double lim = {p}_stop_accel_limit[i];
        double m;
        speed[i] = fabs(v[i]);
        sign[i] = (double)((v[i] > 0.0) - (v[i] < 0.0));
        steps[i] = ceil((speed[i] - lim / rate) / (lim * {P}_DT));
        if (steps[i] < 0.0) steps[i] = 0.0;
        m = speed[i] - lim * {P}_DT * steps[i];
        v_m[i] = sign[i] * (m < 0.0 ? 0.0 : m);
    }}
    for (int k = 0; k < n; ++k) {{
        const double kk = (double)k;
        double fastest = 0.0, row[AD];
        for (int i = 0; i < AD; ++i) {{
            const double lim = {p}_stop_accel_limit[i];
            const int clipped = kk < steps[i];
            const double e = kk - steps[i] < 0.0 ? 0.0 : kk - steps[i];
            const double vel = clipped ? sign[i] * (speed[i] - lim * {P}_DT * kk)
                                       : v_m[i] * pow(1.0 - rate * {P}_DT, e);
            row[i] = clipped ? -sign[i] * lim : -rate * vel;
            if (fabs(vel) > fastest) fastest = fabs(vel);
        }}
        still = still || fastest <= {P}_REST_VELOCITY;
        for (int i = 0; i < AD; ++i) a[k * AD + i] = still ? 0.0 : row[i];
    }}
}}

static void to_outputs({p}_generator *g, const double *x, double *values, int n)
{{
#if {P}_STOP_OUTPUTS == 2
    /* the outputs that give these accelerations along the path from x (the dynamics' outputs_for) */
    memset(g->pad, 0, sizeof g->pad);
    memcpy(g->pad, values, (size_t)n * AD * sizeof(double));
    {p}_outputs_for(x, g->pad, g->physics, g->states);
    memcpy(values, g->states, (size_t)n * AD * sizeof(double));
#else
    (void)g; (void)x; (void)values; (void)n;
#endif
}}
#endif

static void stop({p}_generator *g, const double *x, int n, double *out)
{{
#if !{P}_HAS_VELOCITY
    (void)g; (void)x;
    memset(out, 0, (size_t)n * AD * sizeof(double));
#else
    double v[AD];
    for (int i = 0; i < AD; ++i) v[i] = x[{p}_velocity_columns[i]];
#if !{P}_CONSTRAINT
    stop_accel(v, n, 1.0, out);
    to_outputs(g, x, out, n);
#else
    double worst[NS + 1];
    int pick = -1;
    for (int r = 0; r <= NS; ++r) {{
        if (r < NS) stop_accel(v, n, {p}_stop_shrink[r], g->cand[r]);
        else memset(g->cand[r], 0, (size_t)n * AD * sizeof(double)); /* coasting */
        to_outputs(g, x, g->cand[r], n);
        predict(g, x, g->cand[r], n, g->states);
        memset(g->v_states, 0, sizeof g->v_states);
        memset(g->v_accel, 0, sizeof g->v_accel);
        for (int i = 0; i < SD; ++i) g->v_states[i] = (float)x[i];
        for (int i = 0; i < n * SD; ++i) g->v_states[SD + i] = (float)g->states[i];
        for (int i = 0; i < n * AD; ++i) g->v_accel[i] = (float)g->cand[r][i];
        {p}_violation(g->v_states, g->v_accel, g->v_out);  /* causal: the first n are the n samples' */
        worst[r] = (double)g->v_out[0];
        for (int k = 1; k < n; ++k)
            if ((double)g->v_out[k] > worst[r]) worst[r] = (double)g->v_out[k];
    }}
    {{
        const double limit = (worst[NS] > 0.0 ? worst[NS] : 0.0) + {P}_VIOLATION_TOLERANCE;
        for (int r = 0; r < NS && pick < 0; ++r)
            if (worst[r] <= limit) pick = r;  /* the largest factor no worse than not decelerating */
        if (pick < 0) {{
            pick = 0;  /* stop promptly where even coasting breaks the constraint, else the least violating */
            if (!(worst[NS] > {P}_VIOLATION_TOLERANCE))
                for (int r = 1; r < NS; ++r)
                    if (worst[r] < worst[pick]) pick = r;
        }}
    }}
    memcpy(out, g->cand[pick], (size_t)n * AD * sizeof(double));
#endif
#endif
}}

static void prepare_at({p}_generator *g, int j)
{{
    /* what the correction at position j reads that no measurement changes: pi(W_pred) */
    for (int i = 0; i < (CH - j) * SD; ++i) g->window_p[i] = (float)g->window[j * SD + i];
    for (int i = 0; i < j * SD; ++i) g->window_p[(CH - j) * SD + i] = (float)g->pred[i];
    {p}_decoder_step(g->h, g->c, g->window_p, g->h_scratch, g->c_scratch, g->mean_p);
    g->prepared = j;
}}

void {p}_generator_prepare({p}_generator *g)
{{
    /* the next call's correction (one measured state, between boundaries, in the motion) prepared now */
    const long tau = g->t - g->origin + 1;
    const int j = (int)(tau % CH);
    long left = g->length - 1 - (tau - j);
    if (left > CH) left = CH;
    if (!g->started || !g->replan || !g->planned || j == 0 || left - j <= 0 || g->prepared == j) return;
    prepare_at(g, j);
}}

static int emit({p}_generator *g, double *out)
{{
    const long tau = g->t - g->origin;
    const long k = tau / CH;
    const int j = (int)(tau % CH);
    const int total = CH - j;
    long left = g->length - 1 - k * CH;
    int motion;
    if (left > CH) left = CH;
    motion = (int)(left - j) > 0 ? (int)(left - j) : 0;
    if (motion > 0) {{
        memcpy(out, g->plan + j * AD, (size_t)motion * AD * sizeof(double));
        if (j > 0 && g->replan) {{
            /* u += pi(W_meas) - pi(W_pred): the chunk's step re-run from its boundary's state on the window with
             * the states measured since, and on the same window with the plan's predicted states (prepared) */
            if (g->prepared != j) prepare_at(g, j);
            g->prepared = -1;
            for (int i = 0; i < (CH - j) * SD; ++i) g->window_m[i] = (float)g->window[j * SD + i];
            for (int i = 0; i < j * SD; ++i) g->window_m[(CH - j) * SD + i] = (float)g->measured[i];
            {p}_decoder_step(g->h, g->c, g->window_m, g->h_scratch, g->c_scratch, g->mean_m);
            for (int i = 0; i < motion * AD; ++i)
                out[i] = out[i] + ((double)g->mean_m[i] - (double)g->mean_p[i]);
        }}
    }}
    if (total > motion) {{
        const double *start = g->latest;
        if (motion > 0 && j == 0) start = g->pred + (motion - 1) * SD;
        else if (motion > 0) {{
            predict(g, g->latest, out, motion, g->states);
            memcpy(g->start, g->states + (motion - 1) * SD, sizeof g->start);
            start = g->start;
        }}
        stop(g, start, total - motion, out + motion * AD);
    }}
    for (int i = 0; i < total * AD; ++i)
        if (!isfinite(out[i])) return {P}_ERR_NAN;  /* never hand NaN to a robot */
    g->available = total;
    return total;
}}

static int boundary({p}_generator *g, double *out)
{{
    const long tau = g->t - g->origin;
    g->prepared = -1;
    if (tau < g->length - 1) {{
        if (tau == 0)
            for (int r = 0; r < CH; ++r) memcpy(g->window + r * SD, g->latest, sizeof g->latest);
        else
            memcpy(g->window, g->measured, sizeof g->window);
        memcpy(g->h, g->h_next, sizeof g->h);
        memcpy(g->c, g->c_next, sizeof g->c);
        decode(g->h, g->c, g->window, CH, g->window, g->h_next, g->c_next, g->window_f, g->mean_f);
        for (int i = 0; i < CH * AD; ++i) g->plan[i] = (double)g->mean_f[i];
        {p}_dynamics(g->latest, g->plan, g->physics, g->pred);
        g->planned = 1;
    }} else
        g->planned = 0;
    return emit(g, out);
}}

int {p}_generator_step({p}_generator *g, const double *measured, int count, double *out)
{{
    int j;
    if (!g->started) {{
        if (measured != NULL) return {P}_ERR_CALL;
        g->started = 1;
        return boundary(g, out);
    }}
    if (measured == NULL || count < 1) return {P}_ERR_CALL;
    if (count > g->available) return {P}_ERR_TOO_MANY;
    if (!usable(measured, count * SD)) return {P}_ERR_STATE;
    j = (int)((g->t - g->origin) % CH);
    memcpy(g->measured + j * SD, measured, (size_t)count * SD * sizeof(double));
    g->t += count;
    memcpy(g->latest, measured + (count - 1) * SD, sizeof g->latest);
    if ((g->t - g->origin) % CH == 0) return boundary(g, out);
    return emit(g, out);
}}

int {p}_rollout(const float *z, const double *x0, long length, const double *physics, double *states,
                double *accel)
{{
    static float h[{P}_LATENT_DIM], c[{P}_LATENT_DIM], h2[{P}_LATENT_DIM], c2[{P}_LATENT_DIM];
    static float window[CH * SD], mean[CH * AD];
    static double x[SD], plan[CH * AD], pred[CH * SD], values[{physics_len}];
    const long steps = length > 1 ? (length - 2) / CH + 1 : 0;
    if (length < 2 || !usable(x0, SD)) return {P}_ERR_ARGUMENT;
    for (int i = 0; i < {physics_len}; ++i) values[i] = physics ? physics[i] : {p}_physics_defaults[i];
    memset(h, 0, sizeof h);
    memcpy(c, z, sizeof c);
    memcpy(x, x0, sizeof x);
    memcpy(states, x0, sizeof x);
    for (int r = 0; r < CH; ++r)
        for (int i = 0; i < SD; ++i) window[r * SD + i] = (float)x0[i];
    for (long step = 0; step < steps; ++step) {{
        {p}_decoder_step(h, c, window, h2, c2, mean);
        memcpy(h, h2, sizeof h);
        memcpy(c, c2, sizeof c);
        for (int i = 0; i < CH * AD; ++i) plan[i] = (double)mean[i];
        {p}_dynamics(x, plan, values, pred);
        for (int r = 0; r < CH; ++r) {{
            const long sample = step * CH + r;  /* u[sample] takes x[sample] to x[sample + 1] */
            if (sample + 1 < length) {{
                memcpy(states + (sample + 1) * SD, pred + r * SD, SD * sizeof(double));
                memcpy(accel + sample * AD, plan + r * AD, AD * sizeof(double));
            }}
        }}
        for (int i = 0; i < CH * SD; ++i) window[i] = (float)pred[i];
        memcpy(x, pred + (CH - 1) * SD, sizeof x);
    }}
    for (long i = 0; i < (length - 1) * AD; ++i)
        if (!isfinite(accel[i])) return {P}_ERR_NAN;
    return 0;
}}
"""


def _causal(session_run: Callable[[np.ndarray, np.ndarray], np.ndarray], s: int, d: int, c: int) -> bool:
    """Whether the constraint's violation of the first n samples is the same whatever follows them (the C
    generator plans the stop's n samples with the graph of C)."""
    rng = np.random.default_rng(2)
    states = (0.3 * rng.standard_normal((1, c + 1, s))).astype(np.float32)
    accel = rng.standard_normal((1, c, d)).astype(np.float32)
    base = session_run(states, accel)
    for n in (1, c // 2, c - 1):
        if n < 1:
            continue
        other_s, other_a = states.copy(), accel.copy()
        other_s[:, n + 1:] += 1.0
        other_a[:, n:] -= 1.0
        if not np.array_equal(session_run(other_s, other_a)[:, :n], base[:, :n]):
            return False
    return True


def export_c(model: Any, out: str | Path, *, prefix: str = "seqmotion", physics: Any = None,
             source: str | None = None) -> dict[str, Any]:
    """Write ``model``'s decoder step, dynamics (and the stop's graphs) and the online generator as C99 into
    ``out`` (module docstring): ``PREFIX_model.h/.c``, ``PREFIX_generator.h/.c``. Returns what was written
    (``files``, ``functions``, ``ops``: the op types compiled, ``contract``).

    Raises:
        ValueError: not a seq2seq model, a prefix that is not a C identifier, an op or a shape the emitter has
            no C form for (by name), a constraint whose violation of a sample depends on later samples, outputs
            the stop cannot make (neither accelerations nor mapped by ``outputs_for``: the stepper refuses them
            too), ``out`` a file or not writable.
    """
    import torch

    from ..core.stepper import stepper_contract
    from ..core.trained import TrainedModel
    from ..io import check_writable_dir, write_durable
    from . import export as onnx_export

    if not isinstance(model, TrainedModel):
        raise ValueError(f"export-c exports sequence-to-sequence motion models, not a {type(model).__name__}")
    if not (isinstance(prefix, str) and prefix.isidentifier() and prefix.isascii() and len(prefix) <= 40):
        raise ValueError(f"prefix must be a C identifier of at most 40 ASCII letters, digits and _, got {prefix!r}")
    target = Path(out)
    if target.exists() and not target.is_dir():
        raise ValueError(f"cannot export into {out}: it is a file, not a folder")
    check_writable_dir(target.parent if not target.exists() else target, shown=str(out))
    physics = model.resolve_physics(physics)
    dynamics = model.dynamics(physics)
    contract = stepper_contract(model, dynamics, physics)
    if contract["velocity_columns"] is not None and contract["stop"]["outputs"] is None:  # as the stepper refuses
        raise ValueError(f"the {model.task_def.name!r} task's outputs are not accelerations of its velocity columns "
                         "and its dynamics define no outputs_for(x, accel): the generator could not bring the robot "
                         "to rest after the motion (give the dynamics outputs_for and a stop_accel_limit)")
    cfg = model.model.cfg
    layers, hidden, c = cfg.layers, cfg.hidden, cfg.chunk
    s, d = model.state_layout.dim, model.accel_layout.dim
    inputs = contract["dynamics"]["physics"]["inputs"]
    vector = np.array([float(getattr(physics, name)) for name in inputs], dtype=np.float64)
    statics = Statics(prefix)
    rng = np.random.default_rng(0)
    functions: dict[str, tuple[str, str]] = {}
    ops: set[str] = set()

    def collect(proto: Any) -> None:
        import onnx

        def walk(graph: Any) -> None:
            for node in graph.node:
                ops.add(node.op_type)
                for a in node.attribute:
                    if a.type == onnx.AttributeProto.GRAPH:
                        walk(a.g)
        walk(proto.graph)

    decoder = onnx_export.to_onnx(
        onnx_export.DecoderStep(model, dynamics), (torch.zeros(layers, 1, hidden), torch.zeros(layers, 1, hidden),
                                                  torch.zeros(1, c, s)),
        ["h", "c", "window"], ["h_out", "c_out", "accel"],
        {"h": {1: "B"}, "c": {1: "B"}, "window": {0: "B"}, "h_out": {1: "B"}, "c_out": {1: "B"}, "accel": {0: "B"}})
    collect(decoder)
    state = (layers, 1, hidden)
    functions["decoder_step"] = Emitter(
        statics, f"{prefix}_decoder_step", decoder,
        [("h", "h", state, F32), ("c", "c", state, F32), ("window", "window", (1, c, s), F32)],
        [("h_out", "h_out"), ("c_out", "c_out"), ("accel", "accel")],
        {"h": rng.standard_normal(state).astype(np.float32), "c": rng.standard_normal(state).astype(np.float32),
         "window": rng.standard_normal((1, c, s)).astype(np.float32)}).emit()
    rollout = {"x": rng.standard_normal((1, s)), "accel": rng.standard_normal((1, c, d)), "physics": vector}
    rollout_inputs = [("x", "x", (1, s), F64), ("accel", "accel", (1, c, d), F64),
                      ("physics", "physics", (max(len(inputs), 1),), F64)]
    if contract["dynamics"]["closed_form"] == "double_integrator":
        dt = float(contract["dt"])
        text = DOUBLE_INTEGRATOR_C.format(p=prefix, d=d, s=s, c=c, dt=literal(dt, F64), dt2=literal(dt ** 2, F64))
        functions["dynamics"] = (text.split("\n{")[0] + ";", text.rstrip("\n"))
    else:
        graph = onnx_export.dynamics_graph(model, physics, inputs)
        collect(graph)
        functions["dynamics"] = Emitter(statics, f"{prefix}_dynamics", graph, rollout_inputs,
                                        [("states", "states")], rollout).emit()
    if contract["stop"]["outputs"] == "outputs_for":
        graph = onnx_export.outputs_for_graph(model, physics, inputs)
        collect(graph)
        functions["outputs_for"] = Emitter(statics, f"{prefix}_outputs_for", graph, rollout_inputs,
                                           [("outputs", "outputs")], rollout).emit()
    if contract["constraint"]:
        import onnxruntime as ort

        graph = onnx_export.to_onnx(
            onnx_export.Violation(model), (torch.zeros(1, 3, s), torch.zeros(1, 2, d)), ["states", "accel"],
            ["violation"], {"states": {0: "B", 1: "N1"}, "accel": {0: "B", 1: "N"}, "violation": {0: "B", 1: "N"}})
        collect(graph)
        session = ort.InferenceSession(graph.SerializeToString(), providers=["CPUExecutionProvider"])
        taken = [i.name for i in session.get_inputs()]

        def run(states: np.ndarray, accel: np.ndarray) -> np.ndarray:
            given = {"states": states, "accel": accel}
            return session.run(None, {k: given[k] for k in taken})[0]
        if not _causal(run, s, d, c):
            raise ValueError(f"the {model.task_def.name!r} task's constraint makes the violation of a sample depend on "
                             "later samples: the C generator plans the stop's last samples of a chunk with the "
                             "constraint of the whole chunk, which would differ; export-c needs a violation per sample")
        functions["violation"] = Emitter(
            statics, f"{prefix}_violation", graph,
            [("states", "states", (1, c + 1, s), F32), ("accel", "accel", (1, c, d), F32)],
            [("violation", "violation")],
            {"states": (0.1 * rng.standard_normal((1, c + 1, s))).astype(np.float32),
             "accel": rng.standard_normal((1, c, d)).astype(np.float32)}).emit()
    # the header and the sources
    stop = contract["stop"]
    velocity = contract["velocity_columns"]
    P = prefix.upper()
    values = contract["dynamics"]["physics"]["values"]
    physics_len = max(len(inputs), 1)

    def c_list(items: Sequence[Any], dtype: np.dtype) -> str:
        return "{" + ", ".join(literal(v, dtype) for v in items) + "}"

    def c_string(text: str) -> str:
        return '"' + "".join(ch if ch.isprintable() and ch not in '"\\' and ch.isascii() else f"\\{ord(ch):03o}"
                             for ch in str(text).encode("utf-8").decode("latin-1")) + '"'

    def c_strings(items: Sequence[str]) -> str:
        return "{" + ", ".join(c_string(v) for v in items) + "}"

    declarations = [decl.replace(" *restrict ", " *") for decl, _ in functions.values()]
    extra = ""
    if "outputs_for" in functions:
        extra += (f" *   {prefix}_outputs_for: x (S) and accelerations of the velocity columns (C samples) at "
                  "physics -> outputs (the outputs that give them along the path from x: the stop's).\n")
    if "violation" in functions:
        extra += (f" *   {prefix}_violation: states (C+1) and outputs (C), floats -> the constraint's violation per "
                  "sample (>= 0, 0 where it holds).\n")
    stop_outputs = {None: 0, "accelerations": 1, "outputs_for": 2}[stop["outputs"]]
    fields = dict(
        p=prefix, P=P, task=model.task_def.name, source=source or model.task_def.name, c=c, s=s, d=d,
        input_dim=cfg.encoder_input_dim, layers=layers, hidden=hidden, latent=layers * hidden,
        physics_dim=len(inputs), physics_len=physics_len, dt=literal(float(contract["dt"]), F64),
        default_length=contract["default_length"] or 0, constraint=int(bool(contract["constraint"])),
        stop_outputs=stop_outputs, has_velocity=int(velocity is not None), tau=literal(stop["tau"], F64),
        shrink_count=len(stop["shrink"]), rest=literal(stop["rest_velocity"], F64),
        tolerance=literal(stop["violation_tolerance"], F64),
        physics_doc=("in the order " + ", ".join(inputs)) if inputs else "none read: pass NULL",
        extra_doc=extra, state_kind=contract["state_layout"]["kind"], accel_kind=contract["accel_layout"]["kind"],
        states=", ".join(f"{n} [{u}]" for n, u in zip(contract["state_layout"]["names"],
                                                    contract["state_layout"]["units"], strict=True)),
        accels=", ".join(f"{n} [{u}]" for n, u in zip(contract["accel_layout"]["names"],
                                                    contract["accel_layout"]["units"], strict=True)),
        declarations="\n".join(declarations))
    header = MODEL_H.format(**fields)
    tables = [
        f"const double {prefix}_stop_shrink[{len(stop['shrink'])}] = {c_list(stop['shrink'], F64)};",
        f"const double {prefix}_stop_accel_limit[{d}] = {c_list(stop['accel_limit'], F64)};",
        f"const int {prefix}_velocity_columns[{d}] = {c_list(velocity or [0] * d, I32)};",
        f"const double {prefix}_physics_defaults[{physics_len}] = "
        f"{c_list([values[n] for n in inputs] or [0.0], F64)};",
        f"const char *const {prefix}_physics_names[{physics_len}] = {c_strings(inputs or [''])};",
        f"const char *const {prefix}_state_names[{s}] = {c_strings(contract['state_layout']['names'])};",
        f"const char *const {prefix}_accel_names[{d}] = {c_strings(contract['accel_layout']['names'])};",
    ]
    source_c = "\n\n".join([
        f"/* {prefix}_model.c: the {model.task_def.name!r} model as C99, written by seqmotion export-c (see "
        f"{prefix}_model.h). */\n#include <math.h>\n#include <stdint.h>\n\n#include \"{prefix}_model.h\"",
        TANH_F,
        "\n".join(tables), *statics.lines, *(body for _, body in functions.values())]) + "\n"
    files = {f"{prefix}_model.h": header, f"{prefix}_model.c": source_c,
             f"{prefix}_generator.h": GENERATOR_H.format(**fields),
             f"{prefix}_generator.c": GENERATOR_C.format(**fields)}
    target.mkdir(parents=True, exist_ok=True)
    for name, text in files.items():
        write_durable(target / name, text.encode())
    return {"files": sorted(files), "functions": [f"{prefix}_{k}" for k in functions], "ops": sorted(ops),
            "contract": contract}


def compile_library(out: str | Path, target: str | Path, *, prefix: str = "seqmotion", compiler: str = "cc",
                    flags: Sequence[str] = ("-O2",)) -> Path:
    """Compile the C source ``export_c`` wrote into ``out`` as a shared library at ``target`` (for a check from
    Python through ``ctypes``).

    Raises:
        ValueError: the compiler failed (its first lines in the message).
    """
    import subprocess

    folder = Path(out)
    sources = [str(folder / f"{prefix}_model.c"), str(folder / f"{prefix}_generator.c")]
    done = subprocess.run([compiler, *flags, "-std=c99", "-shared", "-fPIC", *sources, "-o", str(target), "-lm"],
                          capture_output=True, text=True)
    if done.returncode != 0:
        raise ValueError(f"{compiler} failed on {folder}: {' '.join(done.stderr.split())[:600]}")
    return Path(target)


def rollout_c(library: Any, latent: np.ndarray, x0: np.ndarray, length: int, physics: np.ndarray | None = None,
              *, prefix: str = "seqmotion", dim: int) -> tuple[np.ndarray, np.ndarray]:
    """``PREFIX_rollout`` of a library loaded with ``ctypes``: the states ``(K, S)`` and outputs ``(K-1, d)`` the
    C generator's ``generate`` gives from the latent ``(L·H,)`` and the start state ``(S,)`` (``dim``: d; ``physics``
    None: the contract's).

    Raises:
        ValueError: the C function refused (its error code).
    """
    import ctypes

    z = np.ascontiguousarray(latent, dtype=np.float32)
    x = np.ascontiguousarray(x0, dtype=np.float64)
    if int(length) < 2:
        raise ValueError(f"length must be at least 2, got {length}")
    states = np.zeros((int(length), x.size))
    accel = np.zeros((int(length) - 1, int(dim)))
    function = getattr(library, f"{prefix}_rollout")
    function.restype = ctypes.c_int
    vector = None if physics is None else np.ascontiguousarray(physics, dtype=np.float64)

    def ptr(a: np.ndarray | None) -> Any:
        return None if a is None else a.ctypes.data_as(ctypes.c_void_p)
    code = function(ptr(z), ptr(x), ctypes.c_long(length), ptr(vector), ptr(states), ptr(accel))
    if code != 0:
        raise ValueError(f"{prefix}_rollout returned {code}")
    return states, accel


def check_parity(model: Any, out: str | Path, inputs: np.ndarray, *, prefix: str = "seqmotion",
                 compiler: str = "cc") -> dict[str, float]:
    """How far the C source in ``out`` (compiled with ``compiler -O2``) is from PyTorch's ``generate`` on
    ``inputs`` ``(B, K, input_dim)`` (encoded in PyTorch: C has no encoder): the largest difference of the states
    relative to their largest magnitude (``states``) and of the outputs relative to the output scale (``accel``)."""
    import ctypes
    import tempfile

    import torch

    batch = np.asarray(inputs, dtype=np.float64)
    with torch.inference_mode():
        x = torch.from_numpy(batch)
        latent = model.encode_torch(x)
        start = model.start_state(x).double()
        states, accel = model.decode_torch(latent, start, batch.shape[1])
    scale = np.asarray(model.model.cfg.output_scale or [1.0] * model.accel_layout.dim)
    gap = {"states": 0.0, "accel": 0.0}
    with tempfile.TemporaryDirectory(prefix="seqmotion-c-") as scratch:
        library = ctypes.CDLL(str(compile_library(out, Path(scratch) / "model.so", prefix=prefix,
                                                  compiler=compiler)))
        for b in range(batch.shape[0]):
            mine, outputs = rollout_c(library, latent[b].numpy(), start[b].numpy(), batch.shape[1], prefix=prefix,
                                      dim=model.accel_layout.dim)
            ref = states[b].numpy()
            gap["states"] = max(gap["states"], float(np.abs(mine - ref).max() / max(np.abs(ref).max(), 1e-300)))
            gap["accel"] = max(gap["accel"], float((np.abs(outputs - accel[b].numpy()) / scale).max()))
    return gap


__all__ = ["check_parity", "compile_library", "export_c", "rollout_c"]
