/* metrics.c - Prometheus text format writer for /metrics. */
#include "net/metrics.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>

#include "util/util.h"

static void put(sq_metrics *m, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void put(sq_metrics *m, const char *fmt, ...)
{
    for (;;) {
        va_list ap;
        va_start(ap, fmt);
        size_t room = m->cap - m->len;
        int n = vsnprintf(m->text ? m->text + m->len : NULL, m->text ? room : 0, fmt, ap);
        va_end(ap);
        if (n < 0)
            return;
        if (m->text && (size_t)n < room) {
            m->len += (size_t)n;
            return;
        }
        m->cap = SQ_MAX(2 * m->cap, m->len + (size_t)n + 256);
        m->text = sq_realloc(m->text, m->cap);
    }
}

void sq_metrics_family(sq_metrics *m, const char *name, const char *type, const char *help)
{
    put(m, "# HELP %s %s\n# TYPE %s %s\n", name, help, name, type);
}

void sq_metrics_sample(sq_metrics *m, const char *name, const char *labels, double value)
{
    /* integers exactly, others with full precision */
    if (fabs(value) < 9e15 && value == floor(value))
        put(m, "%s%s%s%s %.0f\n", name, labels ? "{" : "", labels ? labels : "", labels ? "}" : "",
            value);
    else
        put(m, "%s%s%s%s %.17g\n", name, labels ? "{" : "", labels ? labels : "", labels ? "}" : "",
            value);
}

void sq_metrics_free(sq_metrics *m)
{
    free(m->text);
    m->text = NULL;
    m->len = m->cap = 0;
}
