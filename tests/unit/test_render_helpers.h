/* test_render_helpers.h - small helpers shared by the render unit tests. */
#ifndef SQ_TEST_RENDER_HELPERS_H
#define SQ_TEST_RENDER_HELPERS_H

#include <math.h>

/* pixels whose colour is a lit version of c: pixel ~ k c for one k in [0.25, 1.4], within
 * max(4, 14 k) per channel (white lights scale the base colour; the tolerance absorbs rounding
 * and specular, and shrinks with k so that dark greys do not match every hue) */
static inline int count_lit(const unsigned char *rgb, int n, const unsigned char c[3])
{
    int count = 0;
    for (int i = 0; i < n; i++) {
        const unsigned char *p = &rgb[3 * i];
        double k = (double)(p[0] + p[1] + p[2]) / (c[0] + c[1] + c[2]);
        if (k < 0.25 || k > 1.4)
            continue;
        int ok = 1;
        for (int j = 0; j < 3; j++)
            ok &= fabs(p[j] - k * c[j]) <= fmax(4.0, 14.0 * k);
        count += ok;
    }
    return count;
}

#endif
