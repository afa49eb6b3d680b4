/* rod_plant: host-side simulated plant for the soft-rod testbed (double precision).
 *
 * Plants (both with the reflected motor inertia J and viscous friction b on the shaft angle):
 *   ROD_PLANT_INEXTENSIBLE  N-link rod of eqs. (7)-(13), exactly gains/rodgains/rod_model.py
 *                           (gravity with sin(theta_i), base inertia J on M_11, friction b on D_11).
 *                           Generalized coordinates: theta_1..theta_N (n = N).
 *   ROD_PLANT_DER           extensible planar discrete elastic rod, exactly gains/rodgains/der_model.py:
 *                           phi (= theta_1, edge 1 clamped in the shaft hub) and the Cartesian
 *                           positions of nodes 2..N (n = 2N - 1), diagonal mass.
 *
 * Motor and driver (MAX14870), chosen by input_mode:
 *   ROD_INPUT_TORQUE  the input is the output-shaft torque [N m] (the paper's idealization);
 *   ROD_INPUT_DUTY    the input is the signed duty in [-1, 1] (clamped):
 *                       V = duty * supply_voltage,
 *                       i = (V - ke_out * omega) / resistance, clamped to +-current_limit
 *                           (the driver's current regulation),
 *                       torque = kt_out * i,   omega = dtheta_1.
 *                     With inductance = 0 the current follows the voltage and the speed at once;
 *                     with inductance > 0 it is a state: L di/dt = V - R i - ke_out omega_m,
 *                     integrated exactly over each step with omega_m held, then clamped.
 *
 * Gearbox (gear_stiffness > 0: compliant; 0: rigid, the motor turns theta_1 itself):
 *   the motor side is its own coordinate theta_m (output-referred), the LAST generalized
 *   coordinate, with the reflected rotor inertia J, the viscous friction b, the Coulomb friction,
 *   the motor torque and the back-EMF. The shaft hub (theta_1) carries output_inertia and
 *   output_viscous. Between them the gear train: torque k x + c (omega_m - omega_1) while the
 *   teeth touch, 0 inside the gap, x = the motor-minus-shaft angle beyond half the backlash on
 *   either side. The encoder reads theta_m. In the limit backlash -> 0, k -> inf it is the rigid
 *   plant (tests/test_plant_gearbox.py).
 *
 * Encoder: count = floor((theta_enc + zero_error) * counts_per_rev / (2 pi) + phase), int32
 * (saturating; INT32_MIN for a non-finite angle); theta_enc = theta_m (compliant) or theta_1.
 *
 * Rest curvature: every flexible joint's bending spring rests at the turning angle
 * rest_curvature x its Voronoi length (EI / its stiffness): a rod that is not straight at rest.
 *
 * Integrators (see rod_plant.c for the derivation; the method and step are chosen by the Python
 * wrapper from the model's linearization, rodctl.sim.plant.choose_integrator):
 *   inextensible, stiff: ROS2, the 2-stage, order-2, L-stable linearly implicit W-method of
 *     Verwer et al. (1999), with the damping (d Lap + b e1 e1' + back-EMF) and the exact Hessian
 *     of the tan bending springs implicit: per stage one SPD solve with
 *     M(theta) + gamma h D + gamma^2 h^2 K, done in O(N) by the articulated-body recursion.
 *   inextensible, mildly stiff (Table I up to N ~ 10): classical RK4, same O(N) solves.
 *   DER: velocity Verlet (symplectic, order 2) for the elastic and gravity forces with the
 *     damping (and back-EMF) integrated implicitly: banded LDL' of diag(m) + h/2 C(q).
 *
 * Nothing here allocates after rod_plant_new(); a plant is not thread-safe (one thread per plant).
 */
#ifndef ROD_PLANT_H
#define ROD_PLANT_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define ROD_PLANT_API_VERSION 4

enum { ROD_PLANT_INEXTENSIBLE = 0, ROD_PLANT_DER = 1 };
enum { ROD_INPUT_TORQUE = 0, ROD_INPUT_DUTY = 1 };
/* Integrators: ROS2 or RK4 for the inextensible rod, VERLET (with implicit damping) for the DER. */
enum { ROD_METHOD_ROS2 = 0, ROD_METHOD_RK4 = 1, ROD_METHOD_VERLET = 2 };

/* Error codes (negative returns). */
enum {
    ROD_OK = 0,
    ROD_ERR_CONFIG = -1,      /* invalid configuration */
    ROD_ERR_NOT_SPD = -2,     /* a pivot was not positive: non-finite state or a singular matrix */
    ROD_ERR_ARGUMENT = -3,    /* bad argument (size, NULL, step) */
    ROD_ERR_ABI = -4          /* controller ABI mismatch or missing function */
};

typedef struct {
    int32_t kind;            /* ROD_PLANT_INEXTENSIBLE or ROD_PLANT_DER */
    int32_t edges;           /* N >= 2 */
    int32_t input_mode;      /* ROD_INPUT_TORQUE or ROD_INPUT_DUTY */
    int32_t method;          /* ROD_METHOD_*: ROS2 or RK4 (inextensible), VERLET (DER) */
    double l;                /* edge length L_tot / N [m] */
    double m;                /* edge mass rho w h l [kg] */
    double EI;               /* bending stiffness [N m^2] */
    double EA;               /* axial stiffness [N] (DER only) */
    double d;                /* inter-edge damping [N m s/rad] */
    double g;                /* gravity [m/s^2] */
    double J;                /* base inertia at the output shaft [kg m^2] */
    double b;                /* base viscous friction [N m s/rad] */
    double kt_out;           /* output torque per ampere [N m/A] */
    double ke_out;           /* back-EMF per output rad/s [V s/rad] */
    double resistance;       /* winding resistance [ohm] */
    double supply_voltage;   /* [V] */
    double current_limit;    /* driver current regulation [A] */
    double counts_per_rev;   /* encoder counts per output revolution (979.2) */
    double encoder_phase;    /* in [0, 1) */
    double max_step;         /* integrator step bound [s] (> 0); advance(dt) takes ceil(dt / max_step - 1 ppm)
                                equal steps */
    /* Edge 1 is the length clamped in the shaft hub: it turns with the shaft and never bends. The
     * paper's model has hub_length = l, hub_mass = m, hub_stiffness = EI / l, hub_damping = d; the
     * faithful plant has a physical hub length independent of N (l = (L - hub) / (N - 1)). */
    double hub_length;       /* length of edge 1 [m] (>= 0; > 0 for the DER; 0 needs J > 0) */
    double hub_mass;         /* mass of edge 1 [kg] */
    double hub_stiffness;    /* bending stiffness of the joint between edge 1 and edge 2 [N m/rad] */
    double hub_damping;      /* damping of that joint [N m s/rad] */
    double coulomb;          /* Coulomb (dry) friction at the output shaft [N m]: -coulomb tanh(omega / coulomb_rate) */
    double coulomb_rate;     /* smoothing rate of the Coulomb friction [rad/s] (> 0) */
    /* gearbox and rig imperfections (all 0: the rigid plant of API version 2) */
    double gear_stiffness;   /* torsional stiffness of the gear train at the output [N m/rad]; 0: rigid */
    double gear_damping;     /* its damping while the teeth touch [N m s/rad] */
    double backlash;         /* total gap at the output [rad] (compliant only) */
    double output_inertia;   /* rod-side inertia of the gearbox: output shaft, last gear, hub [kg m^2] */
    double output_viscous;   /* rod-side viscous friction [N m s/rad] (b and coulomb act on the motor side
                                when compliant, on theta_1 when rigid) */
    double inductance;       /* winding inductance [H] (duty mode); 0: no current lag */
    double zero_error;       /* the encoder reads the angle plus this [rad] */
    double rest_curvature;   /* curvature of the rod at rest [1/m] (0: straight) */
    int32_t encoder_on_shaft; /* 1: the encoder reads theta_1 (an output-shaft encoder), 0: the motor side */
    int32_t imu_on;          /* 1: a 6-axis IMU on the rod (its mass on the rod, its readings to the controller) */
    /* The IMU (imu_on): at arc length imu_position from the axis, on the edge that spans it. Sensor frame
     * x along the rod toward the tip, y its normal toward increasing theta, gyro z = that edge's rate.
     * Each period's sample is the mean over the period that ended imu_delay periods before the read (the
     * part's decimation filter, then the pipelined read), plus white noise, the gyro's bias (a random
     * walk from imu_gyro_bias), rounding to one LSB and clipping at +-32768 LSB. */
    double imu_mass;         /* [kg] */
    double imu_position;     /* [m] from the motor axis along the rod */
    double imu_gyro_sigma;   /* white noise per sample [rad/s] */
    double imu_accel_sigma;  /* [m/s^2] */
    double imu_gyro_bias;    /* turn-on bias [rad/s] */
    double imu_bias_step;    /* the bias's random-walk step per period [rad/s] */
    double imu_gyro_lsb;     /* [rad/s] */
    double imu_accel_lsb;    /* [m/s^2] */
    int32_t imu_delay;       /* periods between the sample's window and the read, 0..ROD_IMU_MAX_DELAY */
    uint32_t imu_seed;       /* noise draws (xorshift32), the same on every machine */
    double imu_fault_time;   /* from this run time on the IMU fails as imu_fault says [s] */
    int32_t imu_fault;       /* ROD_IMU_FAULT_*: 0 none */
    int32_t reserved;
    double imu_tilt;         /* the part's mounting tilt in the swing plane: its frame is the rod's turned by this [rad] */
} rod_plant_config;

#define ROD_IMU_MAX_DELAY 4
enum { ROD_IMU_FAULT_NONE = 0, ROD_IMU_FAULT_SILENT = 1, ROD_IMU_FAULT_STUCK = 2, ROD_IMU_FAULT_RANGE = 3 };

typedef struct rod_plant rod_plant;

int rod_plant_api_version(void);

/* Create a plant at rest hanging straight down (theta = 0), time 0. NULL on an invalid config. */
rod_plant *rod_plant_new(const rod_plant_config *cfg);
void rod_plant_free(rod_plant *p);

int rod_plant_kind(const rod_plant *p);
int rod_plant_edges(const rod_plant *p);
/* Size n of the generalized coordinates: N (inextensible) or 2N - 1 (DER), plus 1 (theta_m, the
 * last) when the gearbox is compliant. */
int rod_plant_size(const rod_plant *p);
int rod_plant_set_max_step(rod_plant *p, double h);
int rod_plant_set_method(rod_plant *p, int method); /* ROD_ERR_ARGUMENT if not valid for the kind */
int rod_plant_method(const rod_plant *p);
double rod_plant_max_step(const rod_plant *p);
int rod_plant_set_encoder_phase(rod_plant *p, double phase);
double rod_plant_time(const rod_plant *p);
void rod_plant_set_time(rod_plant *p, double t);

/* Edge angles and rates theta_1..N, dtheta_1..N (for the DER: an unstretched rod, eq. 6 inverted).
 * The motor side (compliant) is set to theta_1 and its rate, the middle of the gap; the current to 0. */
int rod_plant_set_state(rod_plant *p, const double *theta, const double *dtheta);
/* The motor side: angle theta_m and rate [rad, rad/s] at the output (theta_1 and its rate when rigid),
 * and the winding current [A] (the last step's when inductance = 0). Any pointer may be NULL. */
void rod_plant_motor_state(const rod_plant *p, double *theta_m, double *omega_m, double *current);
int rod_plant_set_motor_state(rod_plant *p, double theta_m, double omega_m, double current);
/* Gear torque on the shaft [N m] at the current state (0 inside the gap; 0 when rigid). */
double rod_plant_gear_torque(const rod_plant *p);
/* Edge angles (unwrapped edge to edge from theta_1) and edge rates omega_k = (e_k x de_k)/|e_k|^2. */
void rod_plant_get_state(const rod_plant *p, double *theta, double *dtheta);
/* Generalized coordinates and their rates, n values each. */
int rod_plant_set_raw_state(rod_plant *p, const double *q, const double *qd);
void rod_plant_get_raw_state(const rod_plant *p, double *q, double *qd);
/* Node positions x_0..x_N as (x, y) pairs, 2(N + 1) values [m]. */
void rod_plant_nodes(const rod_plant *p, double *xy);

/* Kinetic + elastic + gravitational energy [J] (gravity zero at the axis height), the gear train's
 * spring and the motor side's kinetic energy included. */
double rod_plant_energy(const rod_plant *p);

/* Motor torque at the output shaft [N m] for `input` at shaft rate omega; *current gets the
 * current [A] (torque mode: torque / kt_out). */
double rod_plant_motor_torque(const rod_plant *p, double input, double omega, double *current);

/* Time derivative of the raw state y = [q, qd] (2n values) for a held input: dy = [qd, qdd].
 * Uses the plant's workspace (not const); does not change the plant's state. */
int rod_plant_deriv(rod_plant *p, const double *y, double input, double *dy);

/* Generalized force at raw state y: inextensible: T e1 - C - V - D (so M(theta) qdd = F);
 * DER: the node-coordinate force (diag(m) qdd = F). n values (the motor side's last, compliant).
 * With inductance the motor torque is the one of the current state. */
int rod_plant_force(rod_plant *p, const double *y, double input, double *F);

/* Mass matrix at raw state y, n x n row-major (DER: diagonal). */
int rod_plant_mass(rod_plant *p, const double *y, double *M);

/* Integrate dt seconds with the input held: ceil(dt / max_step) equal steps.
 * Returns ROD_OK or a negative error (the state is then left where the failure occurred). */
int rod_plant_advance(rod_plant *p, double input, double dt);

/* Mean torque [N m] and current [A] applied by the motor over the last advance
 * (average over the integrator steps of the torque each step applied). */
double rod_plant_last_torque(const rod_plant *p);
double rod_plant_last_current(const rod_plant *p);

/* An external torque on the shaft [N m] (a disturbance), held until changed; 0 at creation. */
void rod_plant_set_external_torque(rod_plant *p, double torque);

int32_t rod_plant_encoder(const rod_plant *p);
/* The IMU's sample a control step reads now (imu_on), for a caller that steps the plant itself one period at a
 * time (the runner does this on its own): out = gyro, accel x, accel y. Returns 1 (a sample), 0 (none came:
 * the pipeline, or a "silent" fault) or -1 (no IMU). */
int rod_plant_imu_read(rod_plant *p, double period, float out[3]);
/* The count for a given angle (same formula, for tests). */
int32_t rod_plant_encoder_count(const rod_plant *p, double theta1);

/* ---- closed-loop runner ------------------------------------------------------------------
 * The controller is the firmware SIL library, reached through its stable ABI (version 1):
 *   int rod_sil_abi_version(void); void rod_sil_reset(void); float rod_sil_period(void);
 *   int rod_sil_edges(void); void rod_sil_arm(int mode); float rod_sil_step(int32_t count);
 *   int rod_sil_status(float *est, int cap); float rod_sil_duty(void);
 */
typedef void (*rod_sil_reset_fn)(void);
typedef void (*rod_sil_arm_fn)(int mode);
typedef float (*rod_sil_step_fn)(int32_t encoder_count);
typedef int (*rod_sil_status_fn)(float *est, int cap);
typedef float (*rod_sil_duty_fn)(void);
/* The IMU's sample for the coming step: gyro z [rad/s], accelerometer x, y [m/s^2], fresh (0: none came) */
typedef void (*rod_sil_imu_fn)(float gyro, float accel_x, float accel_y, int fresh);

typedef struct {
    rod_sil_reset_fn reset;
    rod_sil_arm_fn arm;
    rod_sil_step_fn step;
    rod_sil_status_fn status;
    rod_sil_duty_fn duty; /* may be NULL in torque mode */
    rod_sil_imu_fn imu;   /* may be NULL: a controller without the IMU (then it is not called) */
} rod_sil_api;

#define ROD_RUN_MAX_EST 256

typedef struct {
    int64_t periods;       /* control periods to run */
    double period;         /* control period [s] (the controller's rod_sil_period()) */
    int32_t est_len;       /* values to read from rod_sil_status (2 * rod_sil_edges()), <= ROD_RUN_MAX_EST */
    int32_t reset;         /* nonzero: rod_sil_reset(), clear the delayed command, then arm */
    int32_t arm_mode;      /* after reset: rod_sil_arm(arm_mode) once if arm_mode != 0 */
    int32_t delay_periods; /* 0: the command acts in the period it was computed; 1: one period later */
    int32_t stop_on_mode;  /* stop after the first period whose mode equals this; -1: never */
    uint32_t jitter_seed;  /* seed of the jitter draws */
    double jitter;         /* control-interrupt jitter [s]: encoder read and new command at t_k + U[0, jitter) */
} rod_run_options;

/* Caller-owned log arrays, one row per period k (any pointer may be NULL):
 *   time[k]          t_k, the time of the encoder read [s]
 *   theta[k*N+i]     true edge angles at t_k (plant N), dtheta likewise
 *   est[k*est_len+j] rod_sil_status after step k (theta-hat then rates)
 *   torque_cmd[k]    rod_sil_step's return
 *   duty[k]          rod_sil_duty() after step k (0 if the controller has none)
 *   torque[k]        mean motor torque applied over [t_k, t_k + period] [N m]
 *   current[k]       mean motor current over the period [A]
 *   mode[k]          rod_sil_status's return
 *   count[k]         the encoder count given to step k
 *   motor[k]         the motor side's angle at the encoder read (theta_1 when rigid) [rad] */
typedef struct {
    double *time;
    double *theta;
    double *dtheta;
    float *est;
    float *torque_cmd;
    float *duty;
    double *torque;
    double *current;
    int32_t *mode;
    int32_t *count;
    double *motor;
    float *imu;  /* imu[3k..3k+2]: the IMU sample given to step k (gyro, accel x, accel y); NaN when none */
} rod_run_log;

typedef struct {
    int64_t periods_run;
    int64_t nonfinite_commands; /* periods whose command was NaN/inf: the plant got 0 instead */
    int32_t stopped_on_mode;    /* 1 if stop_on_mode ended the run */
    int32_t error;              /* ROD_OK or the plant's error */
} rod_run_result;

/* Per period k: count = encoder(plant) -> cmd = step(count) [-> one-period delay] -> hold the
 * torque (torque mode) or rod_sil_duty() (duty mode) for one period while integrating -> log.
 * With jitter > 0 the read and the new command happen at t_k + j_k (j_k uniform in [0, jitter),
 * a fixed sequence from jitter_seed); the log's time stays t_k.
 * Returns the number of periods run, or a negative error. */
int64_t rod_run_closed_loop(rod_plant *p, const rod_sil_api *api, const rod_run_options *opt,
                            const rod_run_log *log, rod_run_result *result);

#ifdef __cplusplus
}
#endif

#endif /* ROD_PLANT_H */
