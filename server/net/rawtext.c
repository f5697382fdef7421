/* rawtext.c - the bytes of a client message before they are JSON: UTF-8 check, ref recovery.
 *
 * A message that is not valid UTF-8 or not valid JSON is refused (bad_json, too_large), but
 * its error still carries the "ref" the client gave, when a scan of the raw text finds one at
 * the top level of an object (docs/protocol.md). Pure functions, used by request.c, fuzzed
 * with it.
 */
#include "net/rawtext.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* offset of the first byte that is not part of valid UTF-8 (RFC 3629: no overlong forms, no
 * surrogates, at most U+10FFFF), or len when all is valid */
size_t sq_utf8_check(const unsigned char *s, size_t len)
{
    size_t i = 0;
    while (i < len) {
        unsigned c = s[i];
        size_t n;
        unsigned min;
        if (c < 0x80) {
            i++;
            continue;
        } else if ((c & 0xE0) == 0xC0) {
            n = 1, min = 0x80, c &= 0x1F;
        } else if ((c & 0xF0) == 0xE0) {
            n = 2, min = 0x800, c &= 0x0F;
        } else if ((c & 0xF8) == 0xF0) {
            n = 3, min = 0x10000, c &= 0x07;
        } else {
            return i;
        }
        for (size_t k = 1; k <= n; k++) {
            if (i + k >= len || (s[i + k] & 0xC0) != 0x80)
                return i;
            c = (c << 6) | (s[i + k] & 0x3F);
        }
        if (c < min || c > 0x10FFFF || (c >= 0xD800 && c <= 0xDFFF))
            return i;
        i += n + 1;
    }
    return len;
}

/* ---- ref recovery from text that is not valid JSON */

static size_t skip_ws(const char *t, size_t i, size_t len)
{
    while (i < len && (t[i] == ' ' || t[i] == '\t' || t[i] == '\n' || t[i] == '\r'))
        i++;
    return i;
}

/* the JSON string starting at t[i] == '"': its end (index after the closing quote), or len
 * when unterminated. When out is given, the value is decoded into it: printable ASCII and
 * the simple escapes only (*ok = 0 for anything else or when it does not fit in cap - 1). */
static size_t scan_string(const char *t, size_t i, size_t len, char *out, size_t cap, int *ok)
{
    size_t n = 0;
    if (ok)
        *ok = 1;
    for (i++; i < len; i++) {
        unsigned char ch = (unsigned char)t[i];
        if (ch == '"') {
            if (out)
                out[n < cap ? n : cap - 1] = 0;
            return i + 1;
        }
        if (ch == '\\') {
            if (++i >= len)
                break;
            static const char esc[] = "\"\\/bfnrt", val[] = "\"\\/\b\f\n\r\t";
            const char *e = strchr(esc, t[i]);
            if (t[i] == 'u' || !e || !*e) {
                if (ok)
                    *ok = 0; /* \uXXXX (or a bad escape): not recovered */
                continue;
            }
            ch = (unsigned char)val[e - esc];
            if (ch < 0x20 && ok)
                *ok = 0; /* control characters are refused in refs */
        } else if (ch < 0x20 || ch > 0x7e) {
            if (ok)
                *ok = 0;
        }
        if (out && n + 1 < cap)
            out[n] = (char)ch;
        if (out && ++n >= cap && ok)
            *ok = 0;
    }
    if (ok)
        *ok = 0;
    return len;
}

/* a top-level "ref" of an object in text that failed to parse: scanned with strings and
 * nesting tracked, so a "ref" inside a string or a nested object is not taken; the first
 * one found is used (as for valid JSON). Sets SQ_REF_STRING/NUMBER, else SQ_REF_NULL. */
void sq_recover_ref(const char *t, size_t len, sq_request *req)
{
    req->ref_kind = SQ_REF_NULL;
    if (!t)
        return;
    size_t i = skip_ws(t, 0, len);
    if (i >= len || t[i] != '{')
        return;
    int depth = 0, expect_key = 0;
    while (i < len) {
        char ch = t[i];
        if (ch == '"') {
            if (depth == 1 && expect_key) {
                char key[8];
                int ok;
                size_t e = scan_string(t, i, len, key, sizeof key, &ok);
                expect_key = 0;
                size_t v = skip_ws(t, e, len);
                if (ok && e < len && !strcmp(key, "ref") && v < len && t[v] == ':') {
                    v = skip_ws(t, v + 1, len);
                    if (v < len && t[v] == '"') {
                        char val[SQ_NET_NAME_MAX];
                        scan_string(t, v, len, val, sizeof val, &ok);
                        if (ok) {
                            req->ref_kind = SQ_REF_STRING;
                            memcpy(req->ref_str, val, sizeof val);
                        }
                        return;
                    }
                    /* a JSON number: -? digits [. digits] [e[+-] digits], then a delimiter */
                    size_t k = v;
                    char num[40];
                    size_t n = 0;
                    while (k < len && n < sizeof num - 1 && strchr("+-.eE0123456789", t[k]) && t[k])
                        num[n++] = t[k++];
                    num[n] = 0;
                    size_t after = skip_ws(t, k, len);
                    if (n && (after >= len || t[after] == ',' || t[after] == '}')) {
                        char *end;
                        double x = strtod(num, &end);
                        int digit0 = num[0] == '-' ? num[1] : num[0];
                        if (!*end && isfinite(x) && digit0 >= '0' && digit0 <= '9') {
                            req->ref_kind = SQ_REF_NUMBER;
                            req->ref_num = x;
                        }
                    }
                    return;
                }
                i = e;
                continue;
            }
            i = scan_string(t, i, len, NULL, 0, NULL);
            continue;
        }
        if (ch == '{' || ch == '[') {
            depth++;
            expect_key = depth == 1 && ch == '{';
        } else if (ch == '}' || ch == ']') {
            if (--depth <= 0)
                return; /* the top-level object ended without a ref */
        } else if (ch == ',' && depth == 1) {
            expect_key = 1;
        }
        i++;
    }
}
