/* suggest — the nearest name to a mistyped one.  See suggest.h. */
#include "suggest.h"

#include <string.h>

/* Edit distance with transpositions (optimal string alignment): "outptu"
 * is one step from "output".  Names are short; longer ones are cut. */
static int distance(const char *a, size_t n, const char *b)
{
    enum { MAX = 48 };
    size_t m = strlen(b);
    if (n > MAX || m > MAX) return MAX;
    int d[MAX + 1][MAX + 1];
    for (size_t i = 0; i <= n; i++) d[i][0] = (int)i;
    for (size_t j = 0; j <= m; j++) d[0][j] = (int)j;
    for (size_t i = 1; i <= n; i++)
        for (size_t j = 1; j <= m; j++) {
            int cost = a[i - 1] != b[j - 1];
            int v = d[i - 1][j - 1] + cost;
            if (d[i - 1][j] + 1 < v) v = d[i - 1][j] + 1;
            if (d[i][j - 1] + 1 < v) v = d[i][j - 1] + 1;
            if (i > 1 && j > 1 && a[i - 1] == b[j - 2] && a[i - 2] == b[j - 1] &&
                d[i - 2][j - 2] + 1 < v)
                v = d[i - 2][j - 2] + 1;
            d[i][j] = v;
        }
    return d[n][m];
}

const char *suggest_nearest(const char *word, size_t n, const char *const names[])
{
    const char *best = NULL;
    int best_d = 3;
    for (int i = 0; names[i]; i++) {
        size_t len = strlen(names[i]);
        int d = distance(word, n, names[i]);
        /* two slips in a long name, one in a short one */
        if (d < best_d && (d == 1 || (d == 2 && len >= 7))) best = names[i], best_d = d;
    }
    return best;
}

