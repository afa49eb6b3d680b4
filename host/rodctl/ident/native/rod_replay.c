/* rod_replay.c -- a "controller" with the rod_sil ABI (version 1) that replays recorded duties.
 *
 * The fit drives the C plant with what the firmware logged, period by period; going through the
 * plant's closed-loop runner (rod_run_closed_loop) keeps the whole replay in C instead of one
 * Python call per period. rod_replay_load points at the caller's array (which must outlive the
 * run); step k returns torque[k] and rod_sil_duty() duty[k], then 0 beyond the end.
 */
#include <stddef.h>
#include <stdint.h>

#define REPLAY_API __attribute__((visibility("default")))

static const float *replay_duty;
static const float *replay_torque;
static int64_t replay_n, replay_k;
static float replay_period = 1.0e-3f;
static float last_duty;

REPLAY_API void rod_replay_load(const float *duty, const float *torque, int64_t n, float period)
{
    replay_duty = duty;
    replay_torque = torque;
    replay_n = n;
    replay_k = 0;
    replay_period = period;
    last_duty = 0.0f;
}

REPLAY_API int rod_sil_abi_version(void) { return 1; }
REPLAY_API void rod_sil_reset(void) { replay_k = 0; last_duty = 0.0f; }
REPLAY_API float rod_sil_period(void) { return replay_period; }
REPLAY_API int rod_sil_edges(void) { return 1; }
REPLAY_API void rod_sil_arm(int mode) { (void)mode; }

REPLAY_API float rod_sil_step(int32_t encoder_count)
{
    (void)encoder_count;
    float torque = 0.0f;
    last_duty = 0.0f;
    if (replay_k < replay_n) {
        torque = replay_torque[replay_k];
        last_duty = replay_duty[replay_k];
    }
    replay_k++;
    return torque;
}

REPLAY_API float rod_sil_duty(void) { return last_duty; }

REPLAY_API int rod_sil_status(float *est, int cap)
{
    for (int i = 0; est != NULL && i < cap; i++) {
        est[i] = 0.0f;
    }
    return 5; /* IDENTIFY */
}
