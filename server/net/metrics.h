/* metrics.h - Prometheus text exposition (format 0.0.4) for GET /metrics (internal to
 * server/net). A growing text buffer; the server fills it from its counters. */
#ifndef SQ_NET_METRICS_H
#define SQ_NET_METRICS_H

#include <stddef.h>

typedef struct sq_metrics {
    char *text;
    size_t len, cap;
} sq_metrics;

/* "# HELP name help" and "# TYPE name type" (type: counter, gauge) */
void sq_metrics_family(sq_metrics *m, const char *name, const char *type, const char *help);
/* one sample: name{labels} value (labels: NULL or e.g. "code=\"429\"") */
void sq_metrics_sample(sq_metrics *m, const char *name, const char *labels, double value);
void sq_metrics_free(sq_metrics *m);

#endif
