/* The marching-cubes case table, built from the cube's faces (iso.h says
 * the rule and why it is consistent).  Built once per process at first use:
 * 256 cases, a few microseconds. */
#include <pthread.h>
#include <string.h>

#include "iso.h"

static iso_case cases[256];
static pthread_once_t once = PTHREAD_ONCE_INIT;

/* Slot e = axis * 4 + k; k's two bits are the other axes' bits, in the
 * order (axis + 1) % 3, (axis + 2) % 3. */
uint32_t iso_edge_corner(uint32_t e)
{
    uint32_t a = e >> 2, k = e & 3u;
    return (k & 1u) << ((a + 1) % 3) | (k >> 1 & 1u) << ((a + 2) % 3);
}

/* The slot of the edge between corners c and d (one bit apart). */
static uint32_t edge_of(uint32_t c, uint32_t d)
{
    uint32_t x = c ^ d, a = x == 1 ? 0 : x == 2 ? 1 : 2, lo = c & d;
    uint32_t k = (lo >> ((a + 1) % 3) & 1u) | (lo >> ((a + 2) % 3) & 1u) << 1;
    return a * 4 + k;
}

/* Face (axis a, side s)'s corners, counter-clockwise seen from outside:
 * with b, c the next axes (b x c = a), (0,0) (1,0) (1,1) (0,1) in (b, c)
 * seen from +a, the reverse from -a. */
static void face_corners(uint32_t a, uint32_t s, uint32_t out[4])
{
    static const uint32_t bc[4][2] = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
    uint32_t b = (a + 1) % 3, c = (a + 2) % 3;
    for (int i = 0; i < 4; i++) {
        int j = s ? i : (4 - i) % 4;
        out[i] = s << a | bc[j][0] << b | bc[j][1] << c;
    }
}

/* Do two edge slots lie on one face of the cube? */
static int share_face(uint32_t e1, uint32_t e2)
{
    uint32_t a1 = e1 >> 2, a2 = e2 >> 2, c1 = iso_edge_corner(e1), c2 = iso_edge_corner(e2);
    for (uint32_t f = 0; f < 3; f++)
        if (f != a1 && f != a2 && (c1 >> f & 1u) == (c2 >> f & 1u)) return 1;
    return 0;
}

/* next[e]: the segment from crossing e on some face; -1 if none.  On each
 * face, walking its corners counter-clockwise, each exit (inside, then
 * outside) is paired with the next entry: inside on the segment's left. */
static void face_segments(uint32_t cs, int next[12])
{
    for (int e = 0; e < 12; e++) next[e] = -1;
    for (uint32_t f = 0; f < 6; f++) {
        uint32_t q[4];
        face_corners(f >> 1, f & 1u, q);
        for (int j = 0; j < 4; j++) {
            int in0 = cs >> q[j] & 1u, in1 = cs >> q[(j + 1) % 4] & 1u;
            if (!in0 || in1) continue; /* not an exit */
            for (int k = 1; k < 4; k++) {
                int a = cs >> q[(j + k) % 4] & 1u, b = cs >> q[(j + k + 1) % 4] & 1u;
                if (!a && b) {
                    next[edge_of(q[j], q[(j + 1) % 4])] =
                        (int)edge_of(q[(j + k) % 4], q[(j + k + 1) % 4]);
                    break;
                }
            }
        }
    }
}

/* A fan root whose diagonals join no two crossings of one face; -1 if
 * the loop has none. */
static int fan_root(const uint8_t *v, int k)
{
    for (int r = 0; r < k; r++) {
        int ok = 1;
        for (int j = 2; j < k - 1 && ok; j++) ok = !share_face(v[r], v[(r + j) % k]);
        if (ok) return r;
    }
    return -1;
}

static void add_tri(iso_case *c, int a, int b, int d, int flip)
{
    uint8_t *t = c->tri[c->ntri++];
    t[0] = (uint8_t)a;
    t[1] = (uint8_t)(flip ? d : b);
    t[2] = (uint8_t)(flip ? b : d);
}

static void add_loop(iso_case *c, const uint8_t *v, int k, int flip)
{
    int r = k == 3 ? 0 : fan_root(v, k);
    if (r >= 0) {
        for (int j = 1; j < k - 1; j++)
            add_tri(c, v[r], v[(r + j) % k], v[(r + j + 1) % k], flip);
        return;
    }
    int ci = c->ncentre++;
    c->loop_len[ci] = (uint8_t)k;
    memcpy(c->loop[ci], v, (size_t)k);
    for (int j = 0; j < k; j++)
        add_tri(c, v[j], v[(j + 1) % k], (int)(ISO_CENTRE_SLOT + (uint32_t)ci), flip);
}

static void build_case(uint32_t cs, int flip)
{
    iso_case *c = &cases[cs];
    int next[12], seen[12] = {0};
    face_segments(cs, next);
    for (int e = 0; e < 12; e++) {
        if (next[e] < 0 || seen[e]) continue;
        uint8_t v[12];
        int k = 0;
        for (int x = e; !seen[x]; x = next[x]) {
            seen[x] = 1;
            v[k++] = (uint8_t)x;
        }
        add_loop(c, v, k, flip);
    }
}

/* The loops come out with the inside on the left of every face segment;
 * which way that turns the triangles is found once, on case 1 (corner 0
 * inside: the normal of its triangle must point away from it, +x+y+z). */
static void build(void)
{
    build_case(1, 0);
    const uint8_t *t = cases[1].tri[0];
    float p[3][3];
    for (int i = 0; i < 3; i++) {
        uint32_t a = iso_edge_axis(t[i]);
        for (int d = 0; d < 3; d++) p[i][d] = d == (int)a ? 0.5f : 0.0f;
    }
    float u[3], w[3];
    for (int d = 0; d < 3; d++) u[d] = p[1][d] - p[0][d], w[d] = p[2][d] - p[0][d];
    float nx = u[1] * w[2] - u[2] * w[1], ny = u[2] * w[0] - u[0] * w[2],
          nz = u[0] * w[1] - u[1] * w[0];
    int flip = nx + ny + nz < 0;
    memset(cases, 0, sizeof cases);
    for (uint32_t cs = 0; cs < 256; cs++) build_case(cs, flip);
}

const iso_case *iso_cases(void)
{
    pthread_once(&once, build);
    return cases;
}
