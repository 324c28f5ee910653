/* frame — length-prefixed messages on a byte stream.  See frame.h. */
#include "frame.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static uint32_t clamp_max(uint32_t max)
{
    if (max < PROTO_FRAME_MIN_MAX) return PROTO_FRAME_MIN_MAX;
    if (max > PROTO_FRAME_LIMIT_MAX) return PROTO_FRAME_LIMIT_MAX;
    return max;
}

void proto_frame_decoder_init(proto_frame_decoder *d, uint32_t max)
{
    memset(d, 0, sizeof *d);
    d->max = clamp_max(max);
}

void proto_frame_decoder_free(proto_frame_decoder *d)
{
    free(d->buf);
    d->buf = NULL;
    d->cap = 0;
}

void proto_frame_decoder_set_max(proto_frame_decoder *d, uint32_t max)
{
    d->max = clamp_max(max);
}

static int fail(proto_frame_decoder *d, int err, uint32_t bad_len)
{
    d->err = err;
    d->bad_len = bad_len;
    proto_frame_decoder_free(d);
    return err;
}

/* Start the next frame; drop a buffer grown for an unusually large one, so
 * an idle connection holds at most PROTO_FRAME_KEEP_ALLOC. */
static void next_frame(proto_frame_decoder *d)
{
    d->hdr_have = 0;
    d->need = 0;
    d->have = 0;
    d->handed = 0;
    if (d->cap > PROTO_FRAME_KEEP_ALLOC) proto_frame_decoder_free(d);
}

static void advance(const uint8_t **data, size_t *len, size_t n)
{
    *data += n;
    *len -= n;
}

/* Read header bytes; 1 once the length is known and valid. */
static int read_header(proto_frame_decoder *d, const uint8_t **data, size_t *len)
{
    size_t take = PROTO_FRAME_HEADER_BYTES - d->hdr_have;
    if (take > *len) take = *len;
    if (take == 0) return 0;
    memcpy(d->hdr + d->hdr_have, *data, take);
    d->hdr_have += (uint32_t)take;
    advance(data, len, take);
    if (d->hdr_have < PROTO_FRAME_HEADER_BYTES) return 0;

    uint32_t n = (uint32_t)d->hdr[0] << 24 | (uint32_t)d->hdr[1] << 16 |
                 (uint32_t)d->hdr[2] << 8 | d->hdr[3];
    if (n == 0) return fail(d, -EPROTO, 0);
    if (n > d->max) return fail(d, -EMSGSIZE, n);
    d->need = n;
    return 1;
}

/* Room for want bytes of the current frame: grow geometrically with what has
 * arrived, never past the frame's own length (so never past max). */
static int reserve(proto_frame_decoder *d, size_t want)
{
    if (want <= d->cap) return 0;
    size_t cap = d->cap * 2;
    if (cap < PROTO_FRAME_INITIAL_ALLOC) cap = PROTO_FRAME_INITIAL_ALLOC;
    if (cap < want) cap = want;
    if (cap > d->need) cap = d->need;
    uint8_t *p = realloc(d->buf, cap);
    if (!p) return -ENOMEM;
    d->buf = p;
    d->cap = cap;
    return 0;
}

int proto_frame_decode(proto_frame_decoder *d, const uint8_t **data, size_t *len,
                 proto_frame_view *out)
{
    if (d->err) return d->err;
    if (d->handed) next_frame(d);
    if (d->need == 0) {
        int rc = read_header(d, data, len);
        if (rc <= 0) return rc;
    }
    if (d->have == 0 && *len >= d->need) {
        /* The whole message is in this input: no copy. */
        out->data = *data;
        out->len = d->need;
        advance(data, len, d->need);
        next_frame(d);
        return 1;
    }
    size_t take = d->need - d->have;
    if (take > *len) take = *len;
    if (take == 0) return 0;
    if (reserve(d, (size_t)d->have + take) < 0) return fail(d, -ENOMEM, d->need);
    memcpy(d->buf + d->have, *data, take);
    d->have += (uint32_t)take;
    advance(data, len, take);
    if (d->have < d->need) return 0;
    out->data = d->buf;
    out->len = d->need;
    d->handed = 1;
    return 1;
}

int proto_frame_decoder_finish(const proto_frame_decoder *d)
{
    if (d->err) return d->err;
    return proto_frame_decoder_pending(d) ? -EPIPE : 0;
}

size_t proto_frame_decoder_pending(const proto_frame_decoder *d)
{
    if (d->handed) return 0;
    return (size_t)d->hdr_have + d->have;
}

const char *proto_frame_decoder_strerror(const proto_frame_decoder *d, int rc, char *buf,
                                   size_t len)
{
    switch (rc) {
    case 0: snprintf(buf, len, "no error"); break;
    case -EPROTO: snprintf(buf, len, "frame length 0"); break;
    case -EMSGSIZE:
        snprintf(buf, len, "frame length %u is over the limit of %u",
                 d->bad_len, d->max);
        break;
    case -EPIPE:
        snprintf(buf, len, "truncated frame at end of stream (%zu bytes of it)",
                 proto_frame_decoder_pending(d));
        break;
    default: snprintf(buf, len, "%s", strerror(-rc)); break;
    }
    return buf;
}

int proto_frame_encode(const ProtobufCMessage *m, uint8_t **buf, size_t *len)
{
    size_t n = protobuf_c_message_get_packed_size(m);
    if (n == 0) return -EINVAL;
    if (n > PROTO_FRAME_LIMIT_MAX) return -EMSGSIZE;
    uint8_t *p = malloc(PROTO_FRAME_HEADER_BYTES + n);
    if (!p) return -ENOMEM;
    p[0] = (uint8_t)(n >> 24);
    p[1] = (uint8_t)(n >> 16);
    p[2] = (uint8_t)(n >> 8);
    p[3] = (uint8_t)n;
    if (protobuf_c_message_pack(m, p + PROTO_FRAME_HEADER_BYTES) != n) {
        free(p);
        return -EINVAL;
    }
    *buf = p;
    *len = PROTO_FRAME_HEADER_BYTES + n;
    return 0;
}

int proto_frame_encode_request(const Voxd__Request *m, uint8_t **buf, size_t *len)
{
    return proto_frame_encode(&m->base, buf, len);
}

int proto_frame_encode_reply(const Voxd__Reply *m, uint8_t **buf, size_t *len)
{
    return proto_frame_encode(&m->base, buf, len);
}

/* An allocator that refuses once a budget is spent.  It allocates with
 * malloc() and frees with free(), exactly as protobuf-c's default allocator,
 * so the message it built is later freed with the default (NULL) one.
 * oom: malloc itself failed (not the budget), which the caller tells apart
 * from garbage by errno. */
typedef struct {
    size_t left;
    int oom;
} unpack_budget;

static void *budget_alloc(void *ud, size_t size)
{
    unpack_budget *b = ud;
    /* What glibc's malloc really uses: 8 bytes of header, 16-byte steps,
     * 32 at least. */
    size_t cost = (size + 8 + 15) & ~(size_t)15;
    if (cost < 32) cost = 32;
    if (cost < size || cost > b->left) return NULL;
    b->left -= cost;
    void *p = malloc(size ? size : 1);
    if (!p) b->oom = 1;
    return p;
}

static void budget_free(void *ud, void *p)
{
    (void)ud;
    free(p);
}

static ProtobufCMessage *unpack(const ProtobufCMessageDescriptor *desc,
                                const uint8_t *data, size_t len)
{
    unpack_budget b = {PROTO_FRAME_UNPACK_BUDGET(len), 0};
    ProtobufCAllocator a = {budget_alloc, budget_free, &b};
    ProtobufCMessage *m = protobuf_c_message_unpack(desc, &a, len, data);
    if (!m) errno = b.oom ? ENOMEM : EBADMSG;
    return m;
}

Voxd__Request *proto_frame_unpack_request(const uint8_t *data, size_t len)
{
    return (Voxd__Request *)unpack(&voxd__request__descriptor, data, len);
}

Voxd__Reply *proto_frame_unpack_reply(const uint8_t *data, size_t len)
{
    return (Voxd__Reply *)unpack(&voxd__reply__descriptor, data, len);
}
