/* A gain-scheduled PID force controller written in C: gain_scheduled_pid.py, in float32.
 * The interface (docs/controllers-as-code.md): fd_user_init once per run, fd_user_step once per
 * control period; state in static variables, no heap, math.h only.
 *
 * u = K_p(tau_r) e + x + d  with  e = tau_r - tau_s [N m]; K_p from P0 to P0 + P1 as |tau_r|
 * goes from 0 to TAU_SCHEDULE; x integrates I e, held while the output sits on its limit;
 * d = D de/dt through a first-order filter T_F (backward Euler); |u| <= U_MAX. */
#include <math.h>

#define P0 4.0f             /* proportional gain at zero reference [N m/N m] */
#define P1 2.0f             /* added gain at |tau_r| >= TAU_SCHEDULE [N m/N m] */
#define TAU_SCHEDULE 1.0f   /* reference at which the schedule saturates [N m] */
#define I_GAIN 20.0f        /* integral gain [1/s] */
#define D_GAIN 0.05f        /* derivative gain [s] */
#define T_F 0.002f          /* derivative filter time constant [s] */
#define U_MAX 10.0f         /* output limit [N m] */

static float dt, x, d, e_prev;

void fd_user_init(float rate_hz)
{
    dt = 1.0f / rate_hz;
    x = 0.0f;
    d = 0.0f;
    e_prev = 0.0f;
}

float fd_user_step(float tau_r, float tau_s, float theta, float q)
{
    const float e = tau_r - tau_s;
    const float kp = P0 + P1 * fminf(fabsf(tau_r) / TAU_SCHEDULE, 1.0f);
    float u;
    (void)theta;
    (void)q;
    d = (T_F * d + D_GAIN * (e - e_prev)) / (T_F + dt);
    e_prev = e;
    u = kp * e + x + d;
    if (fabsf(u) < U_MAX || u * e < 0.0f) {     /* conditional integration (anti-windup) */
        x += I_GAIN * dt * e;
    }
    return fmaxf(-U_MAX, fminf(U_MAX, u));
}
