/* Loading and compiling job sources, with errors a person can act on. */
#include "source.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "cli.h"

/* "#@ domain a,b" or "#@ domain x0,x1,y0,y1,z0,z1" anywhere in the file. */
static void read_directives(source *s)
{
    const char *p = s->text;
    while ((p = strstr(p, "#@"))) {
        p += 2;
        while (*p == ' ' || *p == '\t') p++;
        if (strncmp(p, "domain", 6) != 0) continue;
        p += 6;
        while (*p == ' ' || *p == '\t') p++;
        char arg[256];
        size_t n = strcspn(p, " \t\r\n");
        if (n >= sizeof arg) continue;
        memcpy(arg, p, n);
        arg[n] = '\0';
        if (cli_parse_domain(arg, s->lo, s->hi) == 0) s->has_domain = 1;
        else cli_error("%s: ignoring bad '#@ domain %s'", s->name, arg);
    }
}

int source_load(source *s, const char *path, const char *expr)
{
    memset(s, 0, sizeof *s);
    if (expr) {
        s->name = "<expr>";
        s->len = strlen(expr);
        s->text = strdup(expr);
        if (!s->text) return -ENOMEM;
        return 0;
    }
    s->name = s->path = path;
    int rc = cli_read_file(path, EXPR_DEFAULT_MAX_SOURCE, &s->text, &s->len);
    if (rc == -EFBIG) {
        cli_error("%s: larger than the %u-byte expression limit", path,
                  EXPR_DEFAULT_MAX_SOURCE);
        return rc;
    }
    if (rc) {
        cli_error("%s: %s", path, strerror(-rc));
        return rc;
    }
    read_directives(s);
    return 0;
}

void source_free(source *s)
{
    free(s->text);
    s->text = NULL;
}

int source_compile(const source *s, const expr_limits *lim, expr_tape **out)
{
    expr_error err;
    int rc = expr_compile(s->text, s->len, lim, out, &err);
    if (rc == 0) return 0;
    cli_text_at at = {s->name, s->text, s->len, err.line, err.col};
    cli_error_at(&at, "%s", err.msg);
    return rc;
}
