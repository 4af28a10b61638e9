/* The firmware interface of an exported controller (twin export).

   One call per control period, at the control rate the design was made for (MTWIP_CONTROL_RATE_HZ):

       mtwip_state_t state;              the whole state: owned by the caller, no globals
       mtwip_config_t config;
       mtwip_default_config(&config);    readings in SI units; set the scales for raw LSB
       mtwip_init(&state, &config);
       every period:
           read the sensors into a mtwip_readings_t (a validity flag per sensor)
           mtwip_step(&state, &readings, &targets, &outputs);
           write outputs.duty[0], outputs.duty[1] to the PWM

   Axes and signs are the twin's: body axes x forward, y left along the axle, z up the body;
   wheel angles relative to the body, positive driving forward; duties in [-1, 1], positive
   driving forward. SI units: rad, rad/s, m/s², m, N·m.

   No dynamic memory, no recursion, no I/O, no mutable global state. */
#ifndef MTWIP_H
#define MTWIP_H

#include <stdint.h>
#include "mtwip_params.h"   /* generated: MTWIP_REAL, the design's identity, the estimator's state type */

typedef struct {
    mtwip_real gyro_scale;            /* rad/s per unit of readings.gyro (1: readings in rad/s) */
    mtwip_real accel_scale;           /* m/s² per unit of readings.accel (1: readings in m/s²) */
    mtwip_real encoder_rad_per_count; /* rad per count of readings.encoder */
    /* the IMU's axes into the body's: v_body = imu_to_body · v_imu (rows). Default: the robot file's
       imu.orientation (the identity for an IMU mounted along the body's axes, or for readings a
       firmware turns itself) */
    mtwip_real imu_to_body[3][3];
} mtwip_config_t;

typedef struct {
    mtwip_real gyro[3];    /* angular rate, the IMU's axes, in units of config.gyro_scale */
    mtwip_real accel[3];   /* specific force, the IMU's axes, in units of config.accel_scale */
    int32_t encoder[2];    /* left, right: counts since power-up (wheel relative to the body) */
    uint8_t gyro_valid, accel_valid, encoder_valid;  /* 1: a new sample at this instant; 0: none */
} mtwip_readings_t;

typedef struct {
    uint8_t has_position; mtwip_real position;  /* m of travel from the start; 0: the position loop off */
    uint8_t has_heading; mtwip_real heading;    /* rad; 0: the heading loop off */
} mtwip_targets_t;

typedef struct {
    mtwip_real duty[2];       /* left, right PWM duty in [-1, 1] */
    uint8_t saturated[2];     /* 1: the current limit or the supply cut the command */
    mtwip_real torque[2];     /* N·m: the wheel torques commanded (ul, ur) */
    mtwip_real u;             /* N·m: the balance controller's total torque */
    mtwip_real theta_off;     /* rad: the position controller's lean */
    mtwip_real u_alpha;       /* N·m per wheel: the direction controller's torque */
    mtwip_real estimate[6];   /* [θ, θ̇, ψ, ψ̇, α, α̇] rad, rad/s: for telemetry */
} mtwip_outputs_t;

/* One sample in SI units, body axes (what the estimator reads; mtwip_step fills it from the readings). */
typedef struct {
    mtwip_real gyro[3];     /* rad/s */
    mtwip_real accel[3];    /* m/s² */
    mtwip_real encoder[2];  /* rad */
    uint8_t has_gyro, has_accel, has_encoder;  /* 1: a new sample (its values may still be non-finite) */
} mtwip_sample_t;

typedef struct {
    mtwip_config_t config;
    uint8_t imu_turned;           /* 1: config.imu_to_body is not the identity */
    mtwip_estimator_t estimator;  /* the estimator's state (mtwip_params.h names its type) */
    mtwip_real command[2];        /* N·m: the torques commanded over the period that just ended */
    uint32_t k;                   /* control periods since mtwip_init */
} mtwip_state_t;

void mtwip_default_config(mtwip_config_t *config);
void mtwip_init(mtwip_state_t *state, const mtwip_config_t *config);
void mtwip_step(mtwip_state_t *state, const mtwip_readings_t *readings, const mtwip_targets_t *targets,
                mtwip_outputs_t *outputs);

/* The parts mtwip_step runs, in its order, for tests and for a firmware that wants them apart. */
void mtwip_estimator_init(mtwip_estimator_t *e);
void mtwip_estimator_start(mtwip_estimator_t *e, const mtwip_sample_t *sample, mtwip_real estimate[6]);
void mtwip_estimator_step(mtwip_estimator_t *e, const mtwip_sample_t *sample, const mtwip_real command[2],
                          mtwip_real estimate[6]);
/* out = (ul, ur, u, theta_off, u_alpha): N·m, N·m, N·m, rad, N·m per wheel */
void mtwip_control(const mtwip_real estimate[6], const mtwip_targets_t *targets, mtwip_real out[5]);
/* the driver's law: duty in [-1, 1] for a torque command (N·m) at the shaft speed omega (rad/s,
   wheel relative to the body); returns 1 where the current limit or the supply cut it */
uint8_t mtwip_motor_duty(mtwip_real torque, mtwip_real omega, mtwip_real *duty);
/* the motors' duties for the torques commanded, each shaft's speed taken from the estimate
   (psi_dot -/+ (b/r) alpha_dot - theta_dot): what mtwip_step does after mtwip_control */
void mtwip_drive(const mtwip_real estimate[6], const mtwip_real torque[2], mtwip_real duty[2], uint8_t saturated[2]);
/* sizeof(mtwip_state_t) and sizeof(mtwip_estimator_t) in bytes, for a host that holds them in its own memory */
uint32_t mtwip_state_size(void);
uint32_t mtwip_estimator_size(void);

#endif
