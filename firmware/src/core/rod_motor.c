/* rod_motor.c -- torque to duty via i R + back-EMF, with the torque and duty limits. */
#include "rod_motor.h"

#include "rod_config.h"

/* Comparisons are false for NaN, so these pass NaN through (fminf/fmaxf would hide it). */
static float clamp(float x, float limit)
{
    if (x > limit) {
        return limit;
    }
    if (x < -limit) {
        return -limit;
    }
    return x;
}

float rod_motor_friction_compensation(float rate)
{
    return ROD_COULOMB_COMP_NM * clamp(rate * (1.0f / ROD_FRICTION_RATE_BAND_RAD_S), 1.0f);
}

rod_drive_t rod_motor_drive(float torque, float rate)
{
    rod_drive_t d;
    float tau = clamp(torque, ROD_TORQUE_MAX_NM);
    float volts = tau * (ROD_MOTOR_R_OHM / ROD_MOTOR_KT_NM_PER_A) + ROD_MOTOR_KE_V_S_PER_RAD * rate;
    float duty = volts * (1.0f / ROD_SUPPLY_V);
    d.duty = clamp(duty, ROD_DUTY_MAX);
    if (d.duty != duty) {
        /* The supply cannot give that voltage: report the torque it does give, still within
         * the driver's current limit. */
        float amps = (d.duty * ROD_SUPPLY_V - ROD_MOTOR_KE_V_S_PER_RAD * rate) * (1.0f / ROD_MOTOR_R_OHM);
        tau = clamp(amps * ROD_MOTOR_KT_NM_PER_A, ROD_TORQUE_MAX_NM);
    }
    d.torque = tau;
    return d;
}
