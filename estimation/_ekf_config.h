/* Generated from estimation/ekf_config.py (KernelConfig) by `python -m estimation.ekf_config`:
   do not edit. The compiled EKF's configuration, read by field name (estimation/_ekf.c). */
#ifndef EKF_CONFIG_H
#define EKF_CONFIG_H

#define EKF_CONFIG_COUNT 43

#define EKF_CONFIG(S, A) \
    S(dt)                             /* s: the filter's step, imu_every control periods */ \
    S(r)                              /* m: the wheels' radius */ \
    S(xi)                             /* m: the IMU's forward position in the body frame */ \
    S(zi)                             /* m: the IMU's height above the axle in the body frame */ \
    S(b_r)                            /* 1: half the track over the wheels' radius, b / r */ \
    S(alpha0)                         /* rad: the heading the encoders' odometry starts from */ \
    S(delta)                          /* rad: one encoder count */ \
    S(g_var)                          /* (rad/s)^2: the gyro's noise per sample (white noise and ADC step) */ \
    S(a_var)                          /* (m/s^2)^2: the accelerometer's noise per sample (white noise and ADC step) */ \
    S(bias_q)                         /* (rad/s)^2: the gyro bias's random-walk variance over one step */ \
    A(gate, 2)                        /* 1: the encoder update's chi-square gate for 1 and 2 degrees of freedom */ \
    A(imu_gate, 2)                    /* 1: the IMU outlier test's chi-square gate for 1 and 2 degrees of freedom */ \
    A(lim, 4)                         /* the ADC's full scale: omega_y, omega_z (rad/s), f_x, f_z (m/s^2) */ \
    S(mdt)                            /* s: the model's step, one control period */ \
    S(m11)                            /* kg m^2: equation (1)'s inertia term m11 */ \
    S(m12)                            /* kg m^2: equation (1)'s inertia term m12 (per cos theta) */ \
    S(m22)                            /* kg m^2: equation (1)'s inertia term m22 */ \
    S(n_bla)                          /* kg m^2: the yaw-pitch inertia coupling of equation (1) */ \
    S(d_b)                            /* N m s/rad: the body-wheel damping, the motors' back-EMF slope included */ \
    S(d_w)                            /* N m s/rad: the wheel-ground damping */ \
    S(g_b)                            /* N m: the gravity torque of equation (1) per sin theta */ \
    S(yaw_damping)                    /* N m s/rad: the yaw's damping */ \
    S(m33)                            /* kg m^2: the yaw inertia upright */ \
    S(g)                              /* m/s^2: the acceleration of gravity */ \
    S(has_motor)                      /* 0/1: the motors' driver is modelled (else ideal torque sources) */ \
    S(compensates)                    /* 0/1: the driver compensates the back-EMF */ \
    S(tau_max)                        /* N m: the stall torque a wheel's command is clipped to */ \
    S(i_tau)                          /* N m: the current limit's torque */ \
    S(sigma_tau)                      /* N m: the PWM step's torque sigma */ \
    S(c_e)                            /* N m s/rad: the back-EMF slope */ \
    S(tol)                            /* 1: the delivered torque's sigma relative to the command */ \
    S(every)                          /* control periods per IMU sample */ \
    S(max_rejects_in_row)             /* encoder samples rejected in a row after which the next is forced in */ \
    S(inside_half)                    /* rad: half the width of the interval an unchanged count keeps its wheel in */ \
    S(stuck_sigmas)                   /* 1: sigma outside that interval at which an unchanged count is implausible */ \
    S(msub)                           /* the model's RK4 steps per control period */ \
    S(tilt_limit)                     /* rad: the physical range's largest |theta| */ \
    S(tilt_var_max)                   /* rad^2: the physical range's largest variance of theta */ \
    S(trapezoid_var)                  /* 1: the trapezoid's error in psi, in (dt |v1 - v| / r)^2 */ \
    S(gyro_extrapolation_samples)     /* 1: the gyro's samples of noise in its innovation against the model */ \
    S(accel_variance_factor)          /* 1: the accelerometer test's variance factor */ \
    S(restore_inflation)              /* 1: a restored state's covariance, times P */ \
    S(restore_jitter)                 /* a restored state's covariance, plus this on the diagonal */

#endif
