/* rawtext.h - client text before JSON parsing (internal to server/net; rawtext.c). */
#ifndef SQ_NET_RAWTEXT_H
#define SQ_NET_RAWTEXT_H

#include <stddef.h>

#include "net/net.h"

/* offset of the first byte that is not part of valid UTF-8 (RFC 3629: no overlong forms, no
 * surrogates, at most U+10FFFF), or len when all is valid */
size_t sq_utf8_check(const unsigned char *s, size_t len);
/* a top-level "ref" of an object in text that failed to parse: sets req's ref to
 * SQ_REF_STRING/NUMBER when one is found, else SQ_REF_NULL */
void sq_recover_ref(const char *t, size_t len, sq_request *req);

#endif
