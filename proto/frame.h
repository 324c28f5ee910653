/* frame — length-prefixed messages on a byte stream (the voxd socket).
 *
 * A frame is a u32 length in network byte order followed by that many bytes
 * of one protobuf message.  A length of 0 or over the receiver's maximum is a
 * protocol violation that ends the connection.
 *
 * proto_frame_decoder is fed whatever a read returned — any split, byte by byte or
 * many frames at once — and hands back complete frames.  Its memory is bounded
 * by the maximum given at init, and it grows only as bytes actually arrive: a
 * peer that announces a large frame and sends nothing more costs nothing but
 * the decoder itself.  A frame that arrives whole inside one read is handed
 * back without a copy.
 *
 * Typical loop (libuv read callback):
 *
 *     const uint8_t *p = buf; size_t n = nread;
 *     proto_frame_view f;
 *     int rc;
 *     while ((rc = proto_frame_decode(&c->dec, &p, &n, &f)) == 1)
 *         handle(c, f.data, f.len);
 *     if (rc < 0) close_connection(c);   // proto_frame_decoder_strerror() says why
 *
 * and at EOF, proto_frame_decoder_finish() tells a clean end from a truncated frame.
 */
#ifndef VOXD_FRAME_H
#define VOXD_FRAME_H

#include <stddef.h>
#include <stdint.h>

#include "voxd.pb-c.h"

#define PROTO_FRAME_HEADER_BYTES 4u
/* Default and hard bounds of a frame's message (config option max_frame). */
#define PROTO_FRAME_DEFAULT_MAX (1u << 20)
#define PROTO_FRAME_MIN_MAX 4096u
#define PROTO_FRAME_LIMIT_MAX (64u << 20)
/* Bytes a reply adds around a ResultChunk's data (tags, lengths, ids): the
 * config keeps chunk_size <= max_frame - PROTO_FRAME_CHUNK_OVERHEAD. */
#define PROTO_FRAME_CHUNK_OVERHEAD 64u
/* The decoder's first allocation, and the capacity it keeps between frames
 * (a larger buffer is freed once its frame has been handed back). */
#define PROTO_FRAME_INITIAL_ALLOC 4096u
#define PROTO_FRAME_KEEP_ALLOC 65536u
/* Unpacking may allocate at most this many bytes for a message of len bytes.
 * The densest valid message, a CSG of minimal nodes (7 wire bytes, ~180
 * bytes of heap with protobuf-c's scratch), needs ~27x; more means a message
 * of thousands of empty sub-messages (2 wire bytes, ~150 bytes unpacked
 * each), which no valid message has: it is refused as garbage instead of
 * amplifying a 1 MiB frame into 75 MiB of heap. */
#define PROTO_FRAME_UNPACK_BUDGET(len) (65536u + 40u * (size_t)(len))

typedef struct {
    uint32_t max;        /* largest message length accepted */
    int err;             /* sticky: 0, or the error that stopped the decoder */
    uint32_t bad_len;    /* the offending length when err is set */
    uint8_t hdr[PROTO_FRAME_HEADER_BYTES];
    uint32_t hdr_have;   /* header bytes received of the current frame */
    uint32_t need;       /* message length of the current frame (hdr complete) */
    uint32_t have;       /* message bytes received of the current frame */
    uint8_t *buf;        /* message bytes of a frame split across reads */
    size_t cap;          /* bytes allocated at buf, <= max */
    int handed;          /* buf holds a frame already handed back */
} proto_frame_decoder;

/* A complete message: valid until the next proto_frame_decode() call on the same
 * decoder, and (when it points into the caller's input) while that input is. */
typedef struct {
    const uint8_t *data;
    uint32_t len;
} proto_frame_view;

/* max: largest message length, PROTO_FRAME_MIN_MAX..PROTO_FRAME_LIMIT_MAX (clamped). */
void proto_frame_decoder_init(proto_frame_decoder *d, uint32_t max);
void proto_frame_decoder_free(proto_frame_decoder *d);
/* Change the limit (a client learns the server's from HelloOk).  Applies to
 * frames whose header has not been read yet. */
void proto_frame_decoder_set_max(proto_frame_decoder *d, uint32_t max);

/* Consume input from *data (*len bytes), advancing both, until one frame is
 * complete.  Returns 1 with *out set (call again for the next frame), 0 when
 * all input is consumed without completing a frame, or a negative errno:
 *   -EPROTO    a frame length of 0;
 *   -EMSGSIZE  a frame length over max;
 *   -ENOMEM    no memory for a frame split across reads.
 * After an error every call returns the same error and consumes nothing. */
int proto_frame_decode(proto_frame_decoder *d, const uint8_t **data, size_t *len,
                 proto_frame_view *out);
/* At EOF: 0 if the stream ended between frames, -EPIPE if it ended inside a
 * frame (header or message), or the decoder's sticky error. */
int proto_frame_decoder_finish(const proto_frame_decoder *d);
/* Bytes of a partial frame buffered so far (header included). */
size_t proto_frame_decoder_pending(const proto_frame_decoder *d);
/* Why the decoder stopped, for a log line: "frame length 0", "frame length
 * 5000000 is over the limit of 1048576", "truncated frame at end of stream". */
const char *proto_frame_decoder_strerror(const proto_frame_decoder *d, int rc, char *buf,
                                   size_t len);

/* Pack a message into one malloc'ed block: 4-byte header then the message.
 * Returns 0, -EINVAL for a message that packs to 0 bytes (nothing set: it
 * could not be framed), -EMSGSIZE over PROTO_FRAME_LIMIT_MAX, -ENOMEM. */
int proto_frame_encode(const ProtobufCMessage *m, uint8_t **buf, size_t *len);
int proto_frame_encode_request(const Voxd__Request *m, uint8_t **buf, size_t *len);
int proto_frame_encode_reply(const Voxd__Reply *m, uint8_t **buf, size_t *len);

/* Unpack one message (NULL for bytes that are not a valid message, or that
 * would need more than PROTO_FRAME_UNPACK_BUDGET(len) bytes of heap: errno
 * EBADMSG; or when malloc failed on the way: errno ENOMEM).  Free with
 * voxd__request__free_unpacked(r, NULL) / voxd__reply__free_unpacked(r, NULL).
 * The result is untrusted until proto_check_request/_reply accepts it. */
Voxd__Request *proto_frame_unpack_request(const uint8_t *data, size_t len);
Voxd__Reply *proto_frame_unpack_reply(const uint8_t *data, size_t len);

#endif
