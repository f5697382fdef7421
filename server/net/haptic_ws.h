/* haptic_ws.h - the service thread's side of the haptic channel (internal to server/net). */
#ifndef SQ_NET_HAPTIC_WS_H
#define SQ_NET_HAPTIC_WS_H

#include "net/server.h"

/* a text message of type "haptic": handled (reply or error sent), returns 1; any other
 * message: 0, untouched */
int net_haptic_request(client *c, const char *text, size_t len);
/* a binary message from a client that starts with SQHP: a pose, answered by a force; t_read
 * (sq_now) when its receive callback began, for the channel's latency */
void net_haptic_binary(client *c, const unsigned char *msg, size_t len, double t_read);
/* a force message that waited in c's FIFO has just been written (clients.c): its pose's
 * read-to-written time into its channel's latency */
void net_haptic_written(client *c, const sq_blob *b);
/* close every channel of client `owner` (it left the session or disconnected) */
void net_haptic_close_owner(sq_session *s, uint64_t owner);
/* "haptic" of a stats reply: the open channels and their counters */
cJSON *net_haptic_stats_json(sq_session *s);

#endif
