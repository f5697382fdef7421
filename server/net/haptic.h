/* haptic.h - the haptic channel: tool poses in at up to 1 kHz, one force out per pose.
 *
 * Internal to server/net. A controller opens a channel for one tool of its session (text
 * request "haptic", docs/protocol.md "Haptic channel"); it then sends small binary pose
 * messages and gets one binary force message back per pose, answered on the service thread
 * from the per-frame linear model of the tool's contact (sq_tool_model, body/haptic.c) through
 * a virtual coupling, never waiting for a frame. The session thread meets the service thread
 * here only under hub->mu, held for copies, never across a step:
 *   service thread -> session thread: the newest coupled tool position (applied at the next frame)
 *   session thread -> service thread: the tool's model after each frame
 */
#ifndef SQ_NET_HAPTIC_H
#define SQ_NET_HAPTIC_H

#include <pthread.h>
#include <stdint.h>

#include "body/body.h"
#include "scene/scene.h"

/* the channel settings' ranges (SQ_HAPTIC_STIFFNESS_MAX ...) are scene/scene.h's, shared with
 * the scene's "haptic" block */
#define SQ_HAPTIC_VERSION 1
#define SQ_HAPTIC_POSE_BYTES 48      /* client -> server, kind 1 */
#define SQ_HAPTIC_FORCE_BYTES 104    /* server -> client, kind 2 */
#define SQ_HAPTIC_KIND_POSE 1
#define SQ_HAPTIC_KIND_FORCE 2
#define SQ_HAPTIC_MAX_RATE 2000.0    /* poses per second per channel (token bucket) */
#define SQ_HAPTIC_BURST 100.0        /* its burst */
#define SQ_HAPTIC_SAFE_RATE 50.0     /* s^-1: the coupling spring passive in every measured run,
                                        stiffness <= SQ_HAPTIC_SAFE_RATE x frame rate x device
                                        mass (docs/protocol.md "Virtual coupling and passivity");
                                        the default spring: 500 N/m at 50 Hz for 0.2 kg */
#define SQ_HAPTIC_DAMPING 2.0        /* default coupling damper, N s/m */
/* force flags */
#define SQ_HAPTIC_F_CONTACT 1u       /* the model had held nodes */
#define SQ_HAPTIC_F_RELEASED 2u      /* a push whose model would pull: force 0 */
#define SQ_HAPTIC_F_NO_MODEL 4u      /* no frame since the channel opened: force 0 */
#define SQ_HAPTIC_F_DISSIPATING 8u   /* the passivity controller added damping to this force */
#define SQ_HAPTIC_F_RELAXING 16u     /* the force is the relaxing model's (Kc and the arm), not
                                        the instantaneous K's */
#define SQ_HAPTIC_BLEND 0.5          /* frame periods of device time over which a new frame's
                                        model is blended in: done well before the next one
                                        comes (a blend as long as the period never ends, and
                                        each model's arrival steps the force) */
#define SQ_HAPTIC_PERIOD 0.02        /* s, the frame period taken for a model that has none */
#define SQ_HAPTIC_TRUST 0.1         /* the relaxing model is used while the last one foretold
                                        the new frame's force within this fraction */
#define SQ_HAPTIC_DEVICE_MASS 0.2    /* default device mass, kg: the passivity controller's
                                        damping stays below mass / pose interval */
#define SQ_HAPTIC_FOCUS 3.0          /* default focus: an adaptive body keeps its finest level
                                        within this many tool sizes of the tool (sq_tool.focus) */

/* the virtual coupling between device and tool: spring and damper */
typedef struct sq_haptic_coupling {
    double stiffness;                /* N/m; 0 = no coupling: the tool is the device */
    double damping;                  /* N s/m, on the device-tool relative velocity */
    double device_mass;              /* kg, the device's moving mass: the passivity controller
                                        adds at most device_mass / dt (dt the pose interval), so
                                        that b dt / m <= 1 (half the bound past which a damper
                                        sampled every dt makes the device ring); 0: the default */
} sq_haptic_coupling;

/* the state of the coupling between two poses (service thread) */
typedef struct sq_haptic_state {
    int has_last;
    double t, xd[3], p[3];           /* last device time, device and tool positions */
    long frame;                      /* the model's frame at the last pose */
    int has_model, model_valid, prev_valid, blending;
    int ever_contact;                /* a pose of this channel has been in contact */
    sq_tool_model model, prev;       /* the model of the last pose, the one blended from */
    double blend_t0;                 /* device time the blend began */
    double force[3];                 /* the force answered to the last pose, N */
    double energy;                   /* J absorbed from the device so far: sum of
                                        -force_k . (xd_k+1 - xd_k) (passivity observer) */
    int contact;                     /* the last pose was in contact */
    double arm[3];                   /* N: the relaxing arm's force (the body's short-time
                                        stiffening K - Kc, relaxing over tau) */
    double arm_ref[3], prev_arm_ref[3]; /* arm at the arrival of model and prev: their f0 holds it */
    int trusted, prev_trusted;       /* model's (prev's) force relaxes (Kc and the arm); 0: K alone */
} sq_haptic_state;

/* one evaluation: what a pose gets back */
typedef struct sq_haptic_out {
    double force[3];                 /* on the device, N */
    double torque[3];                /* box: the model's torque, N m */
    double tool[3];                  /* the coupled tool position, m (forwarded to the step) */
    unsigned flags;                  /* SQ_HAPTIC_F_* */
} sq_haptic_out;

/* the force for device position xd at device time t from model m (valid 0: none yet) with the
 * coupling: tool p solves k (xd - p) + f(p) = 0, f(p) = f0 + K (p - p0), or while the model
 * is trusted the relaxing model between Kc and K (haptic.c: both negative semi-definite, so
 * the system is invertible for k > 0); force = f(p) + c (v_p - v_d), the damper
 * acting only between two poses in contact on the same frame's model (a new model moves the
 * tool at once: that jump is not a velocity). A passivity observer keeps the energy the channel
 * has absorbed from the device (force held over each device step); when it is negative (the
 * channel gave energy back that it never took: a new frame's model can), a damper on the device
 * velocity, at most device_mass / dt, takes that energy back over the next step. A push
 * never pulls: where f(p) points into the body the contact is lost (force 0, p = xd). Pure. */
void sq_haptic_eval(const sq_tool_model *m, int valid, long frame, const sq_haptic_coupling *cp,
                    sq_haptic_state *st, const double xd[3], double t, sq_haptic_out *out);

/* the server's own share of a pose's round trip, pose read (its receive callback) to force
 * written (lws_write returned): a histogram of 2^(k/4) us bins, k = 0 .. SQ_HAPTIC_LAT_BINS-1
 * (1 us .. 0.9 s, 19 % wide), since the channel opened */
#define SQ_HAPTIC_LAT_BINS 80
typedef struct sq_haptic_latency {
    uint32_t bins[SQ_HAPTIC_LAT_BINS];
    long n;
    double max;                      /* s */
} sq_haptic_latency;
void sq_haptic_latency_add(sq_haptic_latency *l, double seconds);
/* the p-quantile (0 < p <= 1), s: the upper edge of its bin (at most max); 0 with no sample */
double sq_haptic_latency_quantile(const sq_haptic_latency *l, double p);

/* the coupling spring passive in every measured run for a device of `mass` kg on frames of
 * `frame_rate` Hz, N/m (SQ_HAPTIC_SAFE_RATE), clamped to the request's range */
double sq_haptic_safe_stiffness(double mass, double frame_rate);

/* one open channel */
typedef struct sq_haptic_channel {
    uint32_t id;                     /* 0: free slot */
    int tool;                        /* tool id */
    uint64_t owner;                  /* client serial */
    int shape;                       /* sq_tool_shape at opening */
    sq_haptic_coupling coupling;
    int stiffness_given;             /* the coupling spring was given: else it follows the
                                        device mass (sq_haptic_safe_stiffness) */
    double focus;                    /* tool sizes kept at the finest level about the tool (the
                                        request's "focus"; 0: the lod's criterion alone) */
    sq_haptic_state state;
    sq_tool_model model;             /* summed over the bodies */
    int model_valid;
    long model_frame;
    int has_pose;                    /* pose: the newest tool position for the next frame */
    double pose[3];
    int ramp;                        /* lockstep: the frame's substeps ramp from the last
                                        frame's pose to this one (the request's "ramp") */
    int ramp_has;                    /* ramp_last: the pose the last frame ended at */
    double ramp_last[3];
    double tokens, last_refill;      /* rate limit */
    double last_error;               /* time of the last error message sent (1 per s) */
    long poses, answered, dropped_rate, dropped_bad;
    sq_haptic_latency latency;       /* answered poses: read to written (service thread) */
} sq_haptic_channel;

/* the newest coupled tool position of a channel slot for the step's substeps: a seqlock
 * (written by the service thread under the hub's mutex, read by the session thread without
 * it: sq_haptic_live_pose) */
typedef struct sq_haptic_live {
    unsigned seq;                    /* odd while written */
    int tool;                        /* tool id; -1: none (closed, or no pose yet) */
    double pos[3];
} sq_haptic_live;

typedef struct sq_haptic_hub {
    pthread_mutex_t mu;
    int nopen;                       /* atomic: open channels (0: the step is untouched) */
    uint32_t next_id;
    long bad_channel;                /* poses on a channel the sender does not own */
    long bad_pose;                   /* pose messages that could not be decoded */
    double model_cpu_s;              /* session-thread CPU time of the last frame's models, s */
    sq_haptic_channel ch[SQ_MAX_TOOLS];
    sq_haptic_live live[SQ_MAX_TOOLS]; /* per slot of ch, never cleared by an opening */
    /* the frame's ramps (session thread only: set by sq_haptic_before_frame) */
    int nramp;
    int ramp_tool[SQ_MAX_TOOLS];
    double ramp_from[SQ_MAX_TOOLS][3], ramp_to[SQ_MAX_TOOLS][3];
} sq_haptic_hub;

struct sq_world;
/* publish slot i's newest tool position (pos NULL: the slot has none), under h->mu */
void sq_haptic_live_publish(sq_haptic_hub *h, int i, int tool, const double *pos);
/* the step's pose source (sq_pose_source_fn, body/body.h; arg the hub): the newest position
 * of tool `id` from an open channel, 1; 0 when none. Lock free: a real-time session's frame
 * reads it at every substep (sq_world_set_pose_source); lockstep sessions do not use it */
int sq_haptic_live_pose(void *hub, int id, double frac, double pos[3]);
/* the lockstep ramp's source: tool `id`'s pose at fraction frac of the frame, interpolated
 * between the pose the last frame ended at and the newest one sent before this step */
int sq_haptic_ramp_pose(void *hub, int id, double frac, double pos[3]);
/* the pose source of a session's next frame (after sq_haptic_before_frame): real time, the
 * newest pose (sq_haptic_live_pose); lockstep, the ramp when a channel asked for it, else
 * NULL (poses at frame starts only) */
sq_pose_source_fn sq_haptic_pose_source(sq_haptic_hub *h, int lockstep);
void sq_haptic_hub_init(sq_haptic_hub *h);
void sq_haptic_hub_free(sq_haptic_hub *h);
/* session thread, before a frame: the newest coupled tool positions into the world's tools */
void sq_haptic_before_frame(sq_haptic_hub *h, struct sq_world *w);
/* session thread, after a frame: the models of the channels' tools (summed over bodies) */
void sq_haptic_after_frame(sq_haptic_hub *h, struct sq_world *w);

/* little-endian codecs of the two binary messages */
typedef struct sq_haptic_pose {
    uint32_t channel, seq;
    double t, pos[3];
} sq_haptic_pose;
/* 0, or -1 with a message naming what is wrong (size, magic, version, kind) */
int sq_haptic_pose_decode(const unsigned char *msg, size_t len, sq_haptic_pose *p, char *why, size_t n);
void sq_haptic_pose_encode(const sq_haptic_pose *p, unsigned char out[SQ_HAPTIC_POSE_BYTES]);
void sq_haptic_force_encode(uint32_t channel, uint32_t seq, uint32_t frame, double t,
                            const sq_haptic_out *o, unsigned char out[SQ_HAPTIC_FORCE_BYTES]);
/* is this binary message a haptic one (magic SQHP)? */
int sq_haptic_is_message(const unsigned char *msg, size_t len);

#endif
