/* arm.c: real code for two of SERVO's nine processes (examples/servo-code.yaml,
 * docs/how-to/real-code.md), the kinematics of a 6-joint arm (the PUMA 560 of the
 * paper's era, standard Denavit-Hartenberg parameters), built by `make` into
 * build/examples/libarm.so with nothing but the header:
 *   cc -std=c11 -O2 -fPIC -shared -Iinclude -o libarm.so examples/code/arm.c -lm
 *
 *   arm_forward_kinematics   joint_state (160 B) -> pose (72 B)
 *   arm_jacobian_transpose   joint_state, setpoint, pose, jacobian -> jt_torque (64 B)
 *
 * Every SERVO buffer is a 16-byte header (the writer's cycle, then 8 bytes kept 0) and
 * little-endian doubles: joint_state holds 6 positions (rad), 6 velocities, 6 torques;
 * pose a position (m) and a unit quaternion (w, x, y, z); setpoint a desired pose and a
 * twist; jt_torque 6 joint torques (N m). The processes that write them may still be
 * skeletons, whose dummy bytes are no numbers: a value that is not finite or not of a
 * plausible size reads as 0 (a position), or as "no setpoint yet". */
#include <math.h>
#include <string.h>

#include "skel_step.h"

SKEL_STEP_DECLARE_ABI;

#define JOINTS 6
#define HEADER 16
#define PLAUSIBLE 1e3 /* beyond this (rad, m), a value is a skeleton's dummy bytes */
#define PI 3.14159265358979323846

static const double DH_A[JOINTS] = { 0.0, 0.4318, 0.0203, 0.0, 0.0, 0.0 };
static const double DH_D[JOINTS] = { 0.0, 0.0, 0.15005, 0.4318, 0.0, 0.0 };
static const double DH_ALPHA[JOINTS] = { PI / 2, 0.0, -PI / 2, PI / 2, -PI / 2, 0.0 };
/* The Cartesian stiffness the Jacobian transpose turns into joint torques. */
static const double STIFFNESS_N_PER_M = 2000.0, STIFFNESS_NM_PER_RAD = 50.0;

typedef double frame_t[4][4];

static double get_f64(const uint8_t *at)
{
    uint64_t bits = 0;
    for (int i = 7; i >= 0; i--) bits = bits << 8 | at[i];
    double v;
    memcpy(&v, &bits, sizeof v);
    return v;
}

static void put_u64(uint8_t *at, uint64_t v)
{
    for (int i = 0; i < 8; i++) at[i] = (uint8_t)(v >> (8 * i));
}

static void put_f64(uint8_t *at, double v)
{
    uint64_t bits;
    memcpy(&bits, &v, sizeof bits);
    put_u64(at, bits);
}

static int plausible(double v) { return isfinite(v) && fabs(v) < PLAUSIBLE; }

/* Joint positions from joint_state; 0 where its bytes hold none. */
static void joint_positions(const skel_step_input_t *in, double q[JOINTS])
{
    for (int j = 0; j < JOINTS; j++) {
        double v = in->nbytes >= HEADER + 8 * (j + 1) ? get_f64(in->bytes + HEADER + 8 * j) : 0.0;
        q[j] = plausible(v) ? v : 0.0;
    }
}

static void identity(frame_t t)
{
    memset(t, 0, sizeof(frame_t));
    for (int i = 0; i < 4; i++) t[i][i] = 1.0;
}

/* T <- T * A_j(q): one standard DH link. */
static void dh_link(frame_t t, int j, double q)
{
    double ct = cos(q), st = sin(q), ca = cos(DH_ALPHA[j]), sa = sin(DH_ALPHA[j]);
    const double a[4][4] = { { ct, -st * ca, st * sa, DH_A[j] * ct },
                             { st, ct * ca, -ct * sa, DH_A[j] * st },
                             { 0.0, sa, ca, DH_D[j] },
                             { 0.0, 0.0, 0.0, 1.0 } };
    frame_t out;
    for (int r = 0; r < 4; r++)
        for (int c = 0; c < 4; c++)
            out[r][c] = t[r][0] * a[0][c] + t[r][1] * a[1][c] + t[r][2] * a[2][c] + t[r][3] * a[3][c];
    memcpy(t, out, sizeof out);
}

/* The frames of the base and of each link's end: frames[0] the base, frames[6] the tool. */
static void chain(const double q[JOINTS], frame_t frames[JOINTS + 1])
{
    identity(frames[0]);
    for (int j = 0; j < JOINTS; j++) {
        memcpy(frames[j + 1], frames[j], sizeof(frame_t));
        dh_link(frames[j + 1], j, q[j]);
    }
}

/* The unit quaternion (w, x, y, z) of a rotation matrix (Shepperd's method). */
static void quaternion(frame_t t, double out[4])
{
    double tr = t[0][0] + t[1][1] + t[2][2];
    if (tr > 0.0) {
        double s = 2.0 * sqrt(tr + 1.0);
        out[0] = s / 4.0, out[1] = (t[2][1] - t[1][2]) / s, out[2] = (t[0][2] - t[2][0]) / s;
        out[3] = (t[1][0] - t[0][1]) / s;
    } else if (t[0][0] > t[1][1] && t[0][0] > t[2][2]) {
        double s = 2.0 * sqrt(1.0 + t[0][0] - t[1][1] - t[2][2]);
        out[0] = (t[2][1] - t[1][2]) / s, out[1] = s / 4.0, out[2] = (t[0][1] + t[1][0]) / s;
        out[3] = (t[0][2] + t[2][0]) / s;
    } else if (t[1][1] > t[2][2]) {
        double s = 2.0 * sqrt(1.0 + t[1][1] - t[0][0] - t[2][2]);
        out[0] = (t[0][2] - t[2][0]) / s, out[1] = (t[0][1] + t[1][0]) / s, out[2] = s / 4.0;
        out[3] = (t[1][2] + t[2][1]) / s;
    } else {
        double s = 2.0 * sqrt(1.0 + t[2][2] - t[0][0] - t[1][1]);
        out[0] = (t[1][0] - t[0][1]) / s, out[1] = (t[0][2] + t[2][0]) / s, out[2] = (t[1][2] + t[2][1]) / s;
        out[3] = s / 4.0;
    }
}

static void header(uint8_t *at, int64_t cycle)
{
    put_u64(at, (uint64_t)cycle);
    put_u64(at + 8, 0);
}

/* Output 0 (pose, 72 B): the tool's position and orientation at the joint positions. */
int arm_forward_kinematics(skel_step_t *step)
{
    if (step->ninputs < 1 || step->noutputs < 1 || step->outputs[0].capacity < HEADER + 7 * 8) return -1;
    double q[JOINTS], quat[4];
    frame_t frames[JOINTS + 1];
    joint_positions(&step->inputs[0], q);
    chain(q, frames);
    quaternion(frames[JOINTS], quat);
    uint8_t *out = step->outputs[0].bytes;
    header(out, step->cycle);
    for (int i = 0; i < 3; i++) put_f64(out + HEADER + 8 * i, frames[JOINTS][i][3]);
    for (int i = 0; i < 4; i++) put_f64(out + HEADER + 24 + 8 * i, quat[i]);
    step->outputs[0].nbytes = HEADER + 7 * 8;
    return 0;
}

/* The desired position from setpoint (its first 3 doubles); 0 when it holds none. */
static int desired_position(const skel_step_input_t *in, double p[3])
{
    if (in->nbytes < HEADER + 24) return 0;
    for (int i = 0; i < 3; i++) {
        p[i] = get_f64(in->bytes + HEADER + 8 * i);
        if (!plausible(p[i])) return 0;
    }
    return 1;
}

/* Output 0 (jt_torque, 64 B): tau = J(q)^T F, F the Cartesian stiffness's wrench toward the
 * setpoint (a hold of the present pose while there is none). J is the geometric Jacobian of
 * the joint positions, computed here: the `jacobian` input's writer may still be a skeleton. */
int arm_jacobian_transpose(skel_step_t *step)
{
    if (step->ninputs < 2 || step->noutputs < 1 || step->outputs[0].capacity < HEADER + JOINTS * 8) return -1;
    double q[JOINTS], goal[3], wrench[6] = { 0 };
    frame_t frames[JOINTS + 1];
    joint_positions(&step->inputs[0], q);
    chain(q, frames);
    const double *tool = (const double[]){ frames[JOINTS][0][3], frames[JOINTS][1][3], frames[JOINTS][2][3] };
    if (desired_position(&step->inputs[1], goal))
        for (int i = 0; i < 3; i++) wrench[i] = STIFFNESS_N_PER_M * (goal[i] - tool[i]);
    /* A small orientation hold: the tool's z axis toward the base's -z. */
    double z[3] = { frames[JOINTS][0][2], frames[JOINTS][1][2], frames[JOINTS][2][2] }, down[3] = { 0, 0, -1 };
    wrench[3] = STIFFNESS_NM_PER_RAD * (z[1] * down[2] - z[2] * down[1]);
    wrench[4] = STIFFNESS_NM_PER_RAD * (z[2] * down[0] - z[0] * down[2]);
    wrench[5] = STIFFNESS_NM_PER_RAD * (z[0] * down[1] - z[1] * down[0]);
    uint8_t *out = step->outputs[0].bytes;
    header(out, step->cycle);
    for (int j = 0; j < JOINTS; j++) {
        /* column j of J: z_j x (tool - o_j) over z_j, both in the base frame */
        double zj[3] = { frames[j][0][2], frames[j][1][2], frames[j][2][2] };
        double r[3] = { tool[0] - frames[j][0][3], tool[1] - frames[j][1][3], tool[2] - frames[j][2][3] };
        double v[3] = { zj[1] * r[2] - zj[2] * r[1], zj[2] * r[0] - zj[0] * r[2], zj[0] * r[1] - zj[1] * r[0] };
        double tau = v[0] * wrench[0] + v[1] * wrench[1] + v[2] * wrench[2]
                   + zj[0] * wrench[3] + zj[1] * wrench[4] + zj[2] * wrench[5];
        put_f64(out + HEADER + 8 * j, tau);
    }
    step->outputs[0].nbytes = HEADER + JOINTS * 8;
    return 0;
}
