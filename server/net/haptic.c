/* haptic.c - the haptic channel's model evaluation, its messages and the session side.
 *
 * Everything here but the two frame hooks is pure (unit-tested): the coupling, the pose and
 * force message codecs. The service thread's part (requests, poses in, forces out) is
 * haptic_ws.c.
 */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "net/haptic.h"
#include "net/le.h"
#include "scene/scene.h"

int sq_haptic_is_message(const unsigned char *msg, size_t len)
{
    return len >= 4 && memcmp(msg, "SQHP", 4) == 0;
}

int sq_haptic_pose_decode(const unsigned char *msg, size_t len, sq_haptic_pose *p, char *why, size_t n)
{
    if (!sq_haptic_is_message(msg, len)) {
        snprintf(why, n, "haptic pose: magic is not SQHP");
        return -1;
    }
    if (len != SQ_HAPTIC_POSE_BYTES) {
        snprintf(why, n, "haptic pose: %zu bytes, a pose is %d", len, SQ_HAPTIC_POSE_BYTES);
        return -1;
    }
    unsigned version = (unsigned)msg[4] | (unsigned)msg[5] << 8;
    if (version != SQ_HAPTIC_VERSION) {
        snprintf(why, n, "haptic pose: version %u, this server speaks %d", version, SQ_HAPTIC_VERSION);
        return -1;
    }
    if (msg[6] != SQ_HAPTIC_KIND_POSE) {
        snprintf(why, n, "haptic pose: kind %u, a pose is kind %d", msg[6], SQ_HAPTIC_KIND_POSE);
        return -1;
    }
    p->channel = get_u32(msg + 8);
    p->seq = get_u32(msg + 12);
    p->t = get_f64(msg + 16);
    for (int c = 0; c < 3; c++)
        p->pos[c] = get_f64(msg + 24 + 8 * c);
    return 0;
}

void sq_haptic_pose_encode(const sq_haptic_pose *p, unsigned char out[SQ_HAPTIC_POSE_BYTES])
{
    memset(out, 0, SQ_HAPTIC_POSE_BYTES);
    memcpy(out, "SQHP", 4);
    out[4] = SQ_HAPTIC_VERSION;
    out[6] = SQ_HAPTIC_KIND_POSE;
    put_u32(out + 8, p->channel);
    put_u32(out + 12, p->seq);
    put_f64(out + 16, p->t);
    for (int c = 0; c < 3; c++)
        put_f64(out + 24 + 8 * c, p->pos[c]);
}

void sq_haptic_force_encode(uint32_t channel, uint32_t seq, uint32_t frame, double t,
                            const sq_haptic_out *o, unsigned char out[SQ_HAPTIC_FORCE_BYTES])
{
    memset(out, 0, SQ_HAPTIC_FORCE_BYTES);
    memcpy(out, "SQHP", 4);
    out[4] = SQ_HAPTIC_VERSION;
    out[6] = SQ_HAPTIC_KIND_FORCE;
    out[7] = (unsigned char)o->flags;
    put_u32(out + 8, channel);
    put_u32(out + 12, seq);
    put_u32(out + 16, frame);
    put_f64(out + 24, t);
    for (int c = 0; c < 3; c++) {
        put_f64(out + 32 + 8 * c, o->force[c]);
        put_f64(out + 56 + 8 * c, o->torque[c]);
        put_f64(out + 80 + 8 * c, o->tool[c]);
    }
}

double sq_haptic_safe_stiffness(double mass, double frame_rate)
{
    const double k = SQ_HAPTIC_SAFE_RATE * frame_rate * mass;
    return k > 0 ? fmin(k, SQ_HAPTIC_STIFFNESS_MAX) : 0;
}

/* f(p) = f0 + K (p - p0) */
static void model_force(const sq_tool_model *m, const double p[3], double f[3])
{
    for (int r = 0; r < 3; r++) {
        f[r] = m->f0[r];
        for (int c = 0; c < 3; c++)
            f[r] += m->K[3 * r + c] * (p[c] - m->p0[c]);
    }
}

/* x = A^-1 b for a 3x3 A (row-major); -1 when singular */
static int solve3(const double A[9], const double b[3], double x[3])
{
    double c0 = A[4] * A[8] - A[5] * A[7], c1 = A[5] * A[6] - A[3] * A[8], c2 = A[3] * A[7] - A[4] * A[6];
    double det = A[0] * c0 + A[1] * c1 + A[2] * c2;
    if (!(fabs(det) > 1e-300))
        return -1;
    double inv[9] = {c0, A[2] * A[7] - A[1] * A[8], A[1] * A[5] - A[2] * A[4],
                     c1, A[0] * A[8] - A[2] * A[6], A[2] * A[3] - A[0] * A[5],
                     c2, A[1] * A[6] - A[0] * A[7], A[0] * A[4] - A[1] * A[3]};
    for (int r = 0; r < 3; r++)
        x[r] = (inv[3 * r] * b[0] + inv[3 * r + 1] * b[1] + inv[3 * r + 2] * b[2]) / det;
    return 0;
}

/* the coupled tool position p and force f of one model for device position xd; returns flags */
static unsigned coupled(const sq_tool_model *m, int valid, const sq_haptic_coupling *cp,
                        const double xd[3], double f[3], double p[3], double torque[3])
{
    memset(f, 0, 3 * sizeof *f);
    memset(torque, 0, 3 * sizeof *torque);
    memcpy(p, xd, 3 * sizeof *p);
    if (!valid)
        return SQ_HAPTIC_F_NO_MODEL;
    if (m->nnodes <= 0)
        return 0;
    if (cp->stiffness > 0) {
        /* (k I - K) p = k xd + f0 - K p0 */
        double A[9], b[3];
        for (int r = 0; r < 3; r++) {
            b[r] = cp->stiffness * xd[r] + m->f0[r];
            for (int c = 0; c < 3; c++) {
                A[3 * r + c] = (r == c ? cp->stiffness : 0) - m->K[3 * r + c];
                b[r] -= m->K[3 * r + c] * m->p0[c];
            }
        }
        if (solve3(A, b, p))
            memcpy(p, xd, 3 * sizeof *p);
    }
    model_force(m, p, f);
    if (m->push && f[0] * m->normal[0] + f[1] * m->normal[1] + f[2] * m->normal[2] > 0) {
        /* the reaction of a push points out of the body (against the normal): past the
         * contact the model would pull; the contact is lost */
        memset(f, 0, 3 * sizeof *f);
        memcpy(p, xd, 3 * sizeof *p);
        return SQ_HAPTIC_F_CONTACT | SQ_HAPTIC_F_RELEASED;
    }
    memcpy(torque, m->torque, 3 * sizeof *torque);
    return SQ_HAPTIC_F_CONTACT;
}

/* The body's force between frames, f(p, t) = f0 + Kc (p - p0) + arm(t) - arm_ref: a standard
 * linear solid. Kc (the free nodes relaxed) is the spring a slow move meets; the arm, a spring
 * D = K - Kc in series with a damper of time constant tau, adds the stiffening a quick move
 * meets before the free nodes follow (K, the free nodes still), relaxing over tau:
 * d arm / dt = D dp/dt - arm / tau. arm_ref is the arm at the model's arrival (the frame's f0
 * already holds the arm's state then). Both elements are passive; a steady move meets Kc, a
 * sudden one K. Over a pose step dt (the move taken as steady within it) the arm becomes
 * e arm + phi D dp, e = exp(-dt / tau), phi = tau (1 - e) / dt. dp is the tool's move the
 * device made, J dxd (J = dp/dxd of the coupling), not the move a new model's blend makes
 * (that one is the body's own reply, already in the new f0); a contact's first pose moves the
 * tool from the frame's p0, dp = p - p0, and meets K. The model handed to the coupling is
 * affine in p: eff, f0' + K' (p - p0). */
typedef struct {
    double e, phi;
    int fresh;       /* the contact's first pose: dp = p - p0 */
    double g[3];     /* else the arm's increment phi D J dxd, N */
} arm_step;

static void arm_model(const sq_tool_model *m, int trusted, const double arm[3], const double arm_ref[3],
                      const arm_step *a, sq_tool_model *eff)
{
    *eff = *m;
    if (!trusted)
        return; /* f0 + K (p - p0) */
    for (int r = 0; r < 3; r++) {
        eff->f0[r] = m->f0[r] + a->e * arm[r] - arm_ref[r] + (a->fresh ? 0 : a->g[r]);
        for (int c = 0; c < 3; c++)
            eff->K[3 * r + c] = m->Kc[3 * r + c] + (a->fresh ? a->phi * (m->K[3 * r + c] - m->Kc[3 * r + c]) : 0);
    }
}

/* the arm's step for a pose at device time t, position xd (st: the state before it) */
static arm_step arm_begin(const sq_haptic_state *st, const sq_haptic_coupling *cp, const double xd[3], double t)
{
    arm_step a = {.e = 1, .phi = 1, .fresh = !(st->has_last && st->contact)};
    const sq_tool_model *m = &st->model;
    const double tau = m->nnodes > 0 ? m->tau : 0;
    const double dt = st->has_last ? t - st->t : 0;
    if (!(tau > 0))
        a.e = a.phi = 0;
    else if (dt > 1e-9 && dt < 1e9) {
        a.e = exp(-dt / tau);
        a.phi = tau * (1 - a.e) / dt;
    }
    if (a.fresh)
        return a;
    double D[9], dxd[3], dp[3];
    for (int k = 0; k < 9; k++)
        D[k] = m->K[k] - m->Kc[k];
    for (int c = 0; c < 3; c++)
        dxd[c] = xd[c] - st->xd[c];
    memcpy(dp, dxd, sizeof dp); /* no coupling: the tool is the device */
    if (cp->stiffness > 0) {
        /* J dxd = k (k I - Kc - phi D)^-1 dxd */
        double A[9], b[3];
        for (int r = 0; r < 3; r++) {
            b[r] = cp->stiffness * dxd[r];
            for (int c = 0; c < 3; c++)
                A[3 * r + c] = (r == c ? cp->stiffness : 0) - m->Kc[3 * r + c] - (st->trusted ? a.phi : 1) * D[3 * r + c];
        }
        if (solve3(A, b, dp))
            memcpy(dp, dxd, sizeof dp);
    }
    for (int r = 0; r < 3; r++)
        a.g[r] = a.phi * (D[3 * r] * dp[0] + D[3 * r + 1] * dp[1] + D[3 * r + 2] * dp[2]);
    return a;
}

void sq_haptic_eval(const sq_tool_model *m, int valid, long frame, const sq_haptic_coupling *cp,
                    sq_haptic_state *st, const double xd[3], double t, sq_haptic_out *out)
{
    memset(out, 0, sizeof *out);
    double f[3];
    /* a new frame's model: blended in over SQ_HAPTIC_BLEND of its frame period (device time)
     * from the one the last pose used, so that the force has no step at the frame rate */
    if (!st->has_model || frame != st->frame) {
        if (st->has_model) {
            st->prev = st->model;
            st->prev_valid = st->model_valid;
            memcpy(st->prev_arm_ref, st->arm_ref, sizeof st->arm_ref);
            st->blend_t0 = t;
            st->blending = 1;
        }
        /* the relaxing model only while the last one foretold this frame's force: a contact
         * that goes on, whose new f0 the last model (with its arm) gave within
         * SQ_HAPTIC_TRUST at the new p0; else (a new contact, a lost one, a split or merge, a
         * tool striking the body) the instantaneous K alone, the stiff and passive end. The arm
         * runs in both, so that the foretelling is always the relaxing model's */
        int trust = 0;
        if (st->has_model && st->model_valid && valid && st->model.nnodes > 0 && m->nnodes > 0 && st->contact) {
            double pred[3], err = 0, mag = 0;
            model_force(&st->model, m->p0, pred); /* f0 + K (p0' - p0): Kc below */
            for (int r = 0; r < 3; r++) {
                for (int c = 0; c < 3; c++)
                    pred[r] -= (st->model.K[3 * r + c] - st->model.Kc[3 * r + c]) * (m->p0[c] - st->model.p0[c]);
                pred[r] += st->arm[r] - st->arm_ref[r];
                err += (pred[r] - m->f0[r]) * (pred[r] - m->f0[r]);
                mag += m->f0[r] * m->f0[r];
            }
            trust = err <= SQ_HAPTIC_TRUST * SQ_HAPTIC_TRUST * mag;
        }
        st->model = *m;
        st->model_valid = valid;
        st->has_model = 1;
        st->frame = frame;
        st->prev_trusted = st->trusted;
        st->trusted = trust;
        memcpy(st->arm_ref, st->arm, sizeof st->arm);
    }
    const double period = st->model.period > 0 ? st->model.period : SQ_HAPTIC_PERIOD;
    double w = st->blending ? (t - st->blend_t0) / (SQ_HAPTIC_BLEND * period) : 1;
    if (!(w < 1))
        st->blending = 0, w = 1;
    if (w < 0)
        w = 0;
    const arm_step as = arm_begin(st, cp, xd, t);
    sq_tool_model eff;
    arm_model(&st->model, st->trusted, st->arm, st->arm_ref, &as, &eff);
    out->flags = coupled(&eff, st->model_valid, cp, xd, f, out->tool, out->torque);
    if (st->blending) {
        double f1[3], p1[3], q1[3];
        arm_model(&st->prev, st->prev_trusted, st->arm, st->prev_arm_ref, &as, &eff);
        unsigned fl = coupled(&eff, st->prev_valid, cp, xd, f1, p1, q1);
        for (int c = 0; c < 3; c++) {
            f[c] = w * f[c] + (1 - w) * f1[c];
            out->tool[c] = w * out->tool[c] + (1 - w) * p1[c];
            out->torque[c] = w * out->torque[c] + (1 - w) * q1[c];
        }
        if ((fl & SQ_HAPTIC_F_CONTACT) && !(fl & SQ_HAPTIC_F_RELEASED))
            out->flags = (out->flags & ~SQ_HAPTIC_F_RELEASED) | SQ_HAPTIC_F_CONTACT;
        if (!(fl & SQ_HAPTIC_F_NO_MODEL))
            out->flags &= ~SQ_HAPTIC_F_NO_MODEL;
    }
    int contact = (out->flags & SQ_HAPTIC_F_CONTACT) && !(out->flags & SQ_HAPTIC_F_RELEASED);
    if (contact && st->trusted)
        out->flags |= SQ_HAPTIC_F_RELAXING;
    double arm1[3] = {0, 0, 0}; /* a lost contact lets the arm go (it held no energy to give back) */
    for (int r = 0; contact && r < 3; r++) {
        arm1[r] = as.e * st->arm[r] + (as.fresh ? 0 : as.g[r]);
        for (int c = 0; as.fresh && c < 3; c++)
            arm1[r] += as.phi * (st->model.K[3 * r + c] - st->model.Kc[3 * r + c]) * (out->tool[c] - st->model.p0[c]);
    }
    memcpy(st->arm, arm1, sizeof arm1);
    if (!contact) {
        memset(st->arm_ref, 0, sizeof st->arm_ref);
        memset(st->prev_arm_ref, 0, sizeof st->prev_arm_ref);
    }
    /* the damper on the tool-device relative velocity (device time differences) */
    double dt = st->has_last ? t - st->t : 0;
    if (st->has_last && cp->damping > 0 && contact && st->contact) {
        if (dt > 1e-5 && dt < 0.1)
            for (int c = 0; c < 3; c++) {
                double vp = (out->tool[c] - st->p[c]) / dt, vd = (xd[c] - st->xd[c]) / dt;
                f[c] += cp->damping * (vp - vd);
            }
    }
    /* the channel's very first pose already in contact (opened on a pressed tool): the body
     * holds the energy of its force, credited as 0.5 |f0|^2 / k, k the stiffest diagonal of K
     * (an underestimate of a spring's f^2 / 2k). A contact that starts later gets no credit:
     * the device brings its energy in itself */
    if (contact && !st->ever_contact && !st->has_last) {
        double k = 0, f2 = 0;
        for (int c = 0; c < 3; c++) {
            k = fmax(k, -st->model.K[4 * c]);
            f2 += st->model.f0[c] * st->model.f0[c];
        }
        if (k > 0)
            st->energy += 0.5 * f2 / k;
        st->ever_contact = 1;
    }
    st->ever_contact |= contact;
    /* passivity observer and controller: the energy absorbed up to this pose */
    if (st->has_last) {
        double dx2 = 0;
        for (int c = 0; c < 3; c++) {
            st->energy -= st->force[c] * (xd[c] - st->xd[c]);
            dx2 += (xd[c] - st->xd[c]) * (xd[c] - st->xd[c]);
        }
        if (st->energy < 0 && dx2 > 0 && dt > 1e-5 && dt < 0.1) {
            /* a damper alpha on v = dx / dt dissipates alpha |v|^2 dt over the next step; at
             * most m / dt, or the sampled damper itself would make the device ring */
            const double mass = cp->device_mass > 0 ? cp->device_mass : SQ_HAPTIC_DEVICE_MASS;
            double alpha = fmin(mass / dt, -st->energy * dt / dx2);
            for (int c = 0; c < 3; c++)
                f[c] -= alpha * (xd[c] - st->xd[c]) / dt;
            out->flags |= SQ_HAPTIC_F_DISSIPATING;
        }
    }
    if (!contact && !(out->flags & SQ_HAPTIC_F_DISSIPATING))
        st->energy = fmin(st->energy, 0); /* out of contact the body keeps nothing to give back */
    memcpy(out->force, f, sizeof f);
    memcpy(st->force, f, sizeof f);
    st->has_last = 1;
    st->contact = contact;
    st->t = t;
    memcpy(st->xd, xd, sizeof st->xd);
    memcpy(st->p, out->tool, sizeof st->p);
}

/* a push is frictionless: its reaction and stiffnesses along the contact normal n only,
 * f0 <- min(0, n.f0) n, K <- min(0, n.K n) n n^T, Kc <- max(n.K n, min(0, n.Kc n)) n n^T (Kc
 * never stiffer than K: a condensation that has not converged is between the two) */
static void frictionless(sq_tool_model *m)
{
    const double *n = m->normal;
    double fn = 0, kn = 0, kc = 0;
    for (int r = 0; r < 3; r++) {
        fn += n[r] * m->f0[r];
        for (int c = 0; c < 3; c++) {
            kn += n[r] * m->K[3 * r + c] * n[c];
            kc += n[r] * m->Kc[3 * r + c] * n[c];
        }
    }
    fn = fmin(fn, 0);
    kn = fmin(kn, 0);
    kc = fmax(kn, fmin(kc, 0));
    for (int r = 0; r < 3; r++) {
        m->f0[r] = fn * n[r];
        for (int c = 0; c < 3; c++) {
            m->K[3 * r + c] = kn * n[r] * n[c];
            m->Kc[3 * r + c] = kc * n[r] * n[c];
        }
    }
}

/* S (symmetric 3x3) is positive semi-definite: its principal minors are >= 0 (less a
 * rounding margin relative to its size) */
static int psd3(const double S[9])
{
    const double tol = -1e-9 * (fabs(S[0]) + fabs(S[4]) + fabs(S[8]));
    const double m2a = S[0] * S[4] - S[1] * S[3], m2b = S[0] * S[8] - S[2] * S[6], m2c = S[4] * S[8] - S[5] * S[7];
    const double det = S[0] * m2c - S[1] * (S[3] * S[8] - S[5] * S[6]) + S[2] * (S[3] * S[7] - S[4] * S[6]);
    const double t2 = tol * fabs(tol), t3 = t2 * fabs(tol);
    return S[0] >= tol && S[4] >= tol && S[8] >= tol && m2a >= t2 && m2b >= t2 && m2c >= t2 && det >= t3;
}

/* a grab's Kc lies between 0 and K (-Kc and Kc - K positive semi-definite), as a condensation
 * does; one that has not converged from a warm start may not, and is then not used */
static int between(const double Kc[9], const double K[9])
{
    double a[9], b[9];
    for (int k = 0; k < 9; k++) {
        a[k] = -Kc[k];
        b[k] = Kc[k] - K[k];
    }
    return psd3(a) && psd3(b);
}

void sq_haptic_hub_init(sq_haptic_hub *h)
{
    memset(h, 0, sizeof *h);
    pthread_mutex_init(&h->mu, NULL);
    h->next_id = 1;
    for (int i = 0; i < SQ_MAX_TOOLS; i++)
        h->live[i].tool = -1;
}

void sq_haptic_latency_add(sq_haptic_latency *l, double seconds)
{
    double us = seconds * 1e6;
    int k = us <= 1 ? 0 : (int)ceil(4 * log2(us));
    l->bins[k < SQ_HAPTIC_LAT_BINS ? k : SQ_HAPTIC_LAT_BINS - 1]++;
    l->n++;
    if (seconds > l->max)
        l->max = seconds;
}

double sq_haptic_latency_quantile(const sq_haptic_latency *l, double p)
{
    if (l->n <= 0)
        return 0;
    long want = (long)ceil(p * (double)l->n), seen = 0;
    for (int k = 0; k < SQ_HAPTIC_LAT_BINS; k++) {
        seen += l->bins[k];
        if (seen >= want && seen > 0)
            return fmin(1e-6 * exp2(k / 4.0), l->max);
    }
    return l->max;
}

void sq_haptic_live_publish(sq_haptic_hub *h, int i, int tool, const double *pos)
{
    sq_haptic_live *L = &h->live[i];
    unsigned s = __atomic_load_n(&L->seq, __ATOMIC_RELAXED);
    __atomic_store_n(&L->seq, s + 1, __ATOMIC_RELAXED);
    __atomic_thread_fence(__ATOMIC_RELEASE);
    int id = pos ? tool : -1;
    __atomic_store_n(&L->tool, id, __ATOMIC_RELAXED);
    for (int c = 0; pos && c < 3; c++)
        __atomic_store(&L->pos[c], (double *)&pos[c], __ATOMIC_RELAXED);
    __atomic_store_n(&L->seq, s + 2, __ATOMIC_RELEASE);
}

int sq_haptic_live_pose(void *hub, int id, double frac, double pos[3])
{
    sq_haptic_hub *h = hub;
    (void)frac; /* the newest, whatever the time within the frame */
    if (!__atomic_load_n(&h->nopen, __ATOMIC_ACQUIRE))
        return 0;
    for (int i = 0; i < SQ_MAX_TOOLS; i++) {
        sq_haptic_live *L = &h->live[i];
        for (;;) {
            unsigned s0 = __atomic_load_n(&L->seq, __ATOMIC_ACQUIRE);
            if (s0 & 1)
                continue; /* being written: a few stores, retried */
            int tool = __atomic_load_n(&L->tool, __ATOMIC_RELAXED);
            double p[3];
            for (int c = 0; c < 3; c++)
                __atomic_load(&L->pos[c], &p[c], __ATOMIC_RELAXED);
            __atomic_thread_fence(__ATOMIC_ACQUIRE);
            if (__atomic_load_n(&L->seq, __ATOMIC_RELAXED) != s0)
                continue;
            if (tool != id)
                break;
            memcpy(pos, p, sizeof p);
            return 1;
        }
    }
    return 0;
}

void sq_haptic_hub_free(sq_haptic_hub *h)
{
    pthread_mutex_destroy(&h->mu);
}

int sq_haptic_ramp_pose(void *hub, int id, double frac, double pos[3])
{
    const sq_haptic_hub *h = hub;
    for (int k = 0; k < h->nramp; k++)
        if (h->ramp_tool[k] == id) {
            for (int c = 0; c < 3; c++)
                pos[c] = h->ramp_from[k][c] + frac * (h->ramp_to[k][c] - h->ramp_from[k][c]);
            return 1;
        }
    return 0;
}

sq_pose_source_fn sq_haptic_pose_source(sq_haptic_hub *h, int lockstep)
{
    if (!lockstep)
        return sq_haptic_live_pose;
    return h->nramp > 0 ? sq_haptic_ramp_pose : NULL;
}

/* each tool's focus: its open channel's, 0 for a tool without one (a closed channel's tool
 * goes back to the lod's criterion alone) */
static void set_focus(sq_world *w, const int *tool, const double *focus, int nopen)
{
    for (int i = 0; i < w->ntools; i++) {
        w->tools[i].focus = 0;
        for (int k = 0; k < nopen; k++)
            if (tool[k] == w->tools[i].id)
                w->tools[i].focus = focus[k];
    }
}

void sq_haptic_before_frame(sq_haptic_hub *h, sq_world *w)
{
    h->nramp = 0;
    if (!__atomic_load_n(&h->nopen, __ATOMIC_ACQUIRE)) {
        set_focus(w, NULL, NULL, 0);
        return;
    }
    int n = 0, ids[SQ_MAX_TOOLS], nopen = 0, open_tool[SQ_MAX_TOOLS];
    double open_focus[SQ_MAX_TOOLS];
    double pos[SQ_MAX_TOOLS][3];
    pthread_mutex_lock(&h->mu);
    for (int i = 0; i < SQ_MAX_TOOLS; i++) {
        sq_haptic_channel *ch = &h->ch[i];
        if (!ch->id)
            continue;
        open_tool[nopen] = ch->tool;
        open_focus[nopen++] = ch->focus;
        if (ch->ramp && (ch->has_pose || ch->ramp_has)) {
            const double *to = ch->has_pose ? ch->pose : ch->ramp_last;
            int k = h->nramp++;
            h->ramp_tool[k] = ch->tool;
            memcpy(h->ramp_from[k], ch->ramp_has ? ch->ramp_last : to, sizeof h->ramp_from[k]);
            memcpy(h->ramp_to[k], to, sizeof h->ramp_to[k]);
            memcpy(ch->ramp_last, to, sizeof ch->ramp_last);
            ch->ramp_has = 1;
        }
        if (ch->has_pose) {
            ids[n] = ch->tool;
            memcpy(pos[n++], ch->pose, sizeof pos[0]);
            ch->has_pose = 0;
        }
    }
    pthread_mutex_unlock(&h->mu);
    for (int k = 0; k < n; k++)
        for (int i = 0; i < w->ntools; i++)
            if (w->tools[i].id == ids[k]) {
                sq_tool t = w->tools[i];
                memcpy(t.pos, pos[k], sizeof t.pos);
                sq_err err = {{0}};
                (void)sq_world_set_tool(w, &t, &err); /* a pose within bounds: cannot fail */
            }
    set_focus(w, open_tool, open_focus, nopen);
}

void sq_haptic_after_frame(sq_haptic_hub *h, sq_world *w)
{
    if (!__atomic_load_n(&h->nopen, __ATOMIC_ACQUIRE))
        return;
    const double c0 = sq_thread_cpu();
    int n = 0, ids[SQ_MAX_TOOLS];
    pthread_mutex_lock(&h->mu);
    for (int i = 0; i < SQ_MAX_TOOLS; i++)
        if (h->ch[i].id)
            ids[n++] = h->ch[i].tool;
    pthread_mutex_unlock(&h->mu);
    sq_tool_model models[SQ_MAX_TOOLS];
    int valid[SQ_MAX_TOOLS];
    for (int k = 0; k < n; k++) {
        sq_tool_model *sum = &models[k];
        memset(sum, 0, sizeof *sum);
        sum->period = w->scene->frame_rate > 0 ? 1.0 / w->scene->frame_rate : 0;
        valid[k] = 0;
        for (int i = 0; i < w->ntools; i++) {
            if (w->tools[i].id != ids[k])
                continue;
            valid[k] = 1;
            memcpy(sum->p0, w->tools[i].pos, sizeof sum->p0);
            sum->push = w->tools[i].shape != SQ_TOOL_GRAB;
            double nsum[3] = {0, 0, 0};
            for (int b = 0; b < w->nbodies; b++) {
                sq_tool_model m;
                if (sq_body_tool_model(w->bodies[b], i, &w->tools[i], &m))
                    continue;
                sum->nnodes += m.nnodes;
                /* f0: the frame's feedback (the held nodes' reaction averaged over its
                 * substeps, what frames report), steadier than the end state's (m.f0), which
                 * carries the fastest oscillations of the nodes around the tool */
                for (int c = 0; c < 3; c++) {
                    sum->f0[c] += w->feedback[b][i].force[c];
                    sum->torque[c] += m.torque[c];
                    nsum[c] += m.nnodes * m.normal[c];
                }
                for (int c = 0; c < 9; c++) {
                    sum->K[c] += m.K[c];
                    sum->Kc[c] += m.Kc[c];
                }
                sum->tau = fmax(sum->tau, m.tau);
            }
            double nn = sqrt(nsum[0] * nsum[0] + nsum[1] * nsum[1] + nsum[2] * nsum[2]);
            if (nn > 0)
                for (int c = 0; c < 3; c++)
                    sum->normal[c] = nsum[c] / nn;
            if (sum->push && sum->nnodes > 0)
                frictionless(sum);
            else if (!between(sum->Kc, sum->K))
                memcpy(sum->Kc, sum->K, sizeof sum->K); /* the relaxing model then is K's */
        }
    }
    pthread_mutex_lock(&h->mu);
    for (int k = 0; k < n; k++)
        for (int i = 0; i < SQ_MAX_TOOLS; i++)
            if (h->ch[i].id && h->ch[i].tool == ids[k]) {
                for (int r = 0; r < h->nramp; r++) /* a ramped frame's feedback belongs to its mean pose */
                    if (h->ramp_tool[r] == ids[k] && valid[k])
                        for (int c = 0; c < 3; c++)
                            models[k].p0[c] = 0.5 * (h->ramp_from[r][c] + h->ramp_to[r][c]);
                h->ch[i].model = models[k];
                h->ch[i].model_valid = valid[k];
                h->ch[i].model_frame = w->frame;
            }
    h->model_cpu_s = sq_thread_cpu() - c0;
    pthread_mutex_unlock(&h->mu);
}
