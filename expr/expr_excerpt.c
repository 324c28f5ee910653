/* expr_excerpt — the source line of an error and a caret under its column,
 * cut to a window around the column when the line is long (a generated
 * expression is often one line of many kilobytes). */
#include <errno.h>
#include <string.h>

#include "expr.h"

/* Where line `line` (1-based) starts in src, and its length without the
 * newline (and without a carriage return before it). */
static int find_line(const char *src, size_t len, int line, size_t *start, size_t *ll)
{
    size_t p = 0;
    for (int l = 1; l < line; l++) {
        const char *nl = memchr(src + p, '\n', len - p);
        if (!nl) return -EINVAL;
        p = (size_t)(nl - src) + 1;
    }
    const char *nl = memchr(src + p, '\n', len - p);
    size_t n = nl ? (size_t)(nl - src) - p : len - p;
    if (n && src[p + n - 1] == '\r') n--;
    *start = p;
    *ll = n;
    return 0;
}

/* One byte as shown: one column per byte, so the caret lines up. */
static char shown(unsigned char c)
{
    if (c == '\t') return ' ';
    return c < 0x20 || c > 0x7e ? '?' : (char)c;
}

int expr_excerpt(const char *src, size_t len, int line, int col, char *buf, size_t n)
{
    size_t start, ll;
    if (n) buf[0] = '\0';
    if (!src || line < 1 || col < 1 || n < EXPR_EXCERPT_MAX ||
        find_line(src, len, line, &start, &ll))
        return -EINVAL;
    size_t c = (size_t)col - 1 < ll ? (size_t)col - 1 : ll; /* ll: just past the end */
    size_t from = 0, to = ll, w = EXPR_EXCERPT_WIDTH;
    if (ll > w) {
        from = c > w / 2 ? c - w / 2 : 0;
        if (from + w > ll) from = ll - w;
        to = from + w;
    }
    char *p = buf;
    *p++ = ' ', *p++ = ' ';
    if (from > 0) memcpy(p, "...", 3), p += 3;
    size_t caret = (size_t)(p - buf) + (c - from);
    for (size_t i = from; i < to; i++) *p++ = shown((unsigned char)src[start + i]);
    if (to < ll) memcpy(p, "...", 3), p += 3;
    *p++ = '\n';
    memset(p, ' ', caret);
    p += caret;
    *p++ = '^';
    *p++ = '\n';
    *p = '\0';
    return 0;
}
