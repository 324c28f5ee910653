/* libFuzzer harness for the .csg parser: any input either parses into a
 * tree whose children all have smaller indices (then one brick of it is
 * evaluated on a small grid) or fails with a message.  A failure aborts. */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "csg.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    char *src = malloc(size + 1);
    if (!src) return 0;
    memcpy(src, data, size);
    src[size] = 0;
    csg_tree *t;
    csg_error err;
    int rc = csg_parse(src, size, &t, &err);
    free(src);
    if (rc) {
        if (!err.msg[0] || err.code != rc) abort();
        return 0;
    }
    for (uint32_t i = 0; i < t->n; i++)
        if (t->node[i].a >= (int32_t)i || t->node[i].b >= (int32_t)i) abort();
    double lo[3] = {-1, -1, -1}, hi[3] = {1, 1, 1};
    grid_spec g;
    err_info gerr = {0};
    csg_eval *e;
    if (!grid_make(lo, hi, 16, &g, &gerr) && !csg_eval_new(t, &g, 8, NULL, &e)) {
        uint8_t buf[512], v;
        uint32_t b[3] = {0, 1, 0};
        int uni;
        if (csg_eval_brick(e, b, buf, &uni, &v)) abort();
        csg_eval_free(e);
    }
    csg_tree_free(t);
    return 0;
}
