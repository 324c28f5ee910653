/* Fuzz the frame decoder: the input is a byte stream (after 3 bytes that
 * pick the frame limit and the read boundaries), fed in pseudo-random
 * pieces.  Every frame is unpacked as a Request and as a Reply and each is
 * validated.  Invariants checked (abort on violation):
 *   - feeding in pieces yields exactly the frames and the error of feeding
 *     the stream at once;
 *   - no frame is longer than the limit; the buffer never exceeds it;
 *   - input is consumed completely unless the decoder stopped on an error. */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "frame.h"
#include "proto_check.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

typedef struct {
    uint64_t hash; /* FNV-1a over every frame's length and bytes */
    int frames;
    int rc;        /* last result: 0 or the error */
    int finish;
} outcome;

static void mix(uint64_t *h, const uint8_t *p, size_t n)
{
    for (size_t i = 0; i < n; i++) *h = (*h ^ p[i]) * 0x100000001b3ull;
}

static void check_frame(const proto_frame_view *f, const proto_limits *lim)
{
    Voxd__Request *rq = proto_frame_unpack_request(f->data, f->len);
    if (rq) {
        proto_error e;
        proto_check_request(rq, lim, &e);
        voxd__request__free_unpacked(rq, NULL);
    }
    Voxd__Reply *rp = proto_frame_unpack_reply(f->data, f->len);
    if (rp) {
        proto_check_reply(rp, lim, NULL);
        voxd__reply__free_unpacked(rp, NULL);
    }
}

/* Decode data in pieces whose sizes come from a xorshift generator (seed 0:
 * all at once). */
static outcome run(const uint8_t *data, size_t size, uint32_t max, uint32_t seed,
                   int validate)
{
    outcome o = {0xcbf29ce484222325ull, 0, 0, 0};
    proto_frame_decoder d;
    proto_frame_decoder_init(&d, max);
    proto_limits lim;
    proto_limits_default(&lim);
    size_t pos = 0;
    uint32_t x = seed | 1;
    while (pos < size && o.rc == 0) {
        size_t piece = size - pos;
        if (seed) {
            x ^= x << 13, x ^= x >> 17, x ^= x << 5;
            piece = 1 + x % (x & 0x100 ? 7 : 4096);
            if (piece > size - pos) piece = size - pos;
        }
        const uint8_t *p = data + pos;
        size_t n = piece;
        proto_frame_view f;
        int rc;
        while ((rc = proto_frame_decode(&d, &p, &n, &f)) == 1) {
            if (f.len == 0 || f.len > d.max) abort();
            uint8_t len[4] = {(uint8_t)(f.len >> 24), (uint8_t)(f.len >> 16),
                              (uint8_t)(f.len >> 8), (uint8_t)f.len};
            mix(&o.hash, len, 4);
            mix(&o.hash, f.data, f.len);
            o.frames++;
            if (validate) check_frame(&f, &lim);
        }
        if (d.cap > d.max) abort();
        if (rc == 0 && n != 0) abort();
        o.rc = rc;
        pos += piece - n;
    }
    o.finish = proto_frame_decoder_finish(&d);
    proto_frame_decoder_free(&d);
    return o;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size < 3) return 0;
    uint32_t max = PROTO_FRAME_MIN_MAX << (data[0] % 4); /* 4K .. 32K: big frames reachable */
    uint32_t seed = (uint32_t)data[1] << 8 | data[2];
    data += 3, size -= 3;
    outcome whole = run(data, size, max, 0, 0);
    outcome split = run(data, size, max, seed ? seed : 1, 1);
    if (whole.hash != split.hash || whole.frames != split.frames ||
        whole.rc != split.rc || whole.finish != split.finish)
        abort();
    return 0;
}
