/* How vox speaks: every error and warning of the CLI goes through here, one
 * line each, prefixed "vox: " (and the command, for a usage error). */
#include "cli.h"
#include "suggest.h"

#include <getopt.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "version.h"

/* What a message quotes of an argument: at most this many bytes, then "...",
 * so that no line grows past a terminal or two whatever was typed. */
#define ARG_SHOWN 40

static void say(const char *prefix, const char *fmt, va_list ap)
{
    char line[1024];
    vsnprintf(line, sizeof line, fmt, ap);
    fprintf(stderr, "vox: %s%s\n", prefix, line);
}

void cli_error(const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    say("", fmt, ap);
    va_end(ap);
}

void cli_note(const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    say("", fmt, ap);
    va_end(ap);
}

void cli_warn(const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    say("warning: ", fmt, ap);
    va_end(ap);
}

int cli_usage_error(const char *cmd, const char *fmt, ...)
{
    char line[768];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(line, sizeof line, fmt, ap);
    va_end(ap);
    if (cmd)
        fprintf(stderr, "vox: %s: %s; see 'vox %s --help'\n", cmd, line, cmd);
    else
        fprintf(stderr, "vox: %s; see 'vox --help'\n", line);
    return CLI_EXIT_USAGE;
}

const char *cli_plural(uint64_t n)
{
    return n == 1 ? "" : "s";
}

void cli_version(const char *prog)
{
    printf("%s %s (commit %s)\n", prog, VOX_VERSION, VOX_COMMIT);
}

/* Options of names that arg ("--comp") begins: getopt's ambiguous case. */
static int prefixed(const char *arg, const char *const names[], char *list, size_t cap)
{
    size_t n = strcspn(arg, "="), used = 0;
    int count = 0;
    list[0] = '\0';
    for (int i = 0; names[i]; i++)
        if (!strncmp(names[i], arg, n) && strlen(names[i]) > n) {
            int w = snprintf(list + used, cap - used, "%s%s", count ? ", " : "", names[i]);
            if (w > 0 && (size_t)w < cap - used) used += (size_t)w;
            count++;
        }
    return count;
}

int cli_unknown_option(const char *cmd, const char *arg, const char *const names[])
{
    int n = (int)strcspn(arg, "=");
    const char *more = n > ARG_SHOWN ? "..." : "";
    if (n > ARG_SHOWN) n = ARG_SHOWN;
    char list[160];
    if (!strncmp(arg, "--", 2) && prefixed(arg, names, list, sizeof list) > 1)
        return cli_usage_error(cmd, "ambiguous option '%.*s%s' (%s?)", n, arg, more, list);
    /* a long option only: one letter is one slip from any other */
    const char *longs[80];
    int k = 0;
    for (int i = 0; names[i] && k < 79; i++)
        if (!strncmp(names[i], "--", 2)) longs[k++] = names[i];
    longs[k] = NULL;
    const char *near = !strncmp(arg, "--", 2) ? suggest_nearest(arg, strcspn(arg, "="), longs)
                                              : NULL;
    if (near)
        return cli_usage_error(cmd, "unknown option '%.*s%s' (did you mean '%s'?)", n, arg,
                               more, near);
    return cli_usage_error(cmd, "unknown option '%.*s%s'", n, arg, more);
}

int cli_unknown_command(const char *cmd, const char *const names[])
{
    const char *near = suggest_nearest(cmd, strlen(cmd), names);
    if (near)
        return cli_usage_error(NULL, "unknown command '%.40s' (did you mean '%s'?)", cmd, near);
    return cli_usage_error(NULL, "unknown command '%.40s'", cmd);
}

/* The long options as "--name" (and the short ones as "-c"), for
 * cli_unknown_option; names has room for cap entries and the NULL. */
static void option_names(const char *shorts, const struct option *longs, char store[][32],
                         const char *names[], int cap)
{
    int k = 0;
    for (int i = 0; longs[i].name && k < cap; i++, k++) {
        snprintf(store[k], sizeof store[k], "--%s", longs[i].name);
        names[k] = store[k];
    }
    for (const char *s = shorts; *s && k < cap; s++)
        if (*s != ':') {
            snprintf(store[k], sizeof store[k], "-%c", *s);
            names[k] = store[k];
            k++;
        }
    names[k] = NULL;
}

static const char *long_name(const struct option *longs, int val)
{
    for (int i = 0; longs[i].name; i++)
        if (longs[i].val == val) return longs[i].name;
    return NULL;
}

/* The message for getopt's '?' or ':' (it printed nothing: opterr = 0). */
static void option_error(const char *cmd, int c, char **argv, const char *shorts,
                         const struct option *longs)
{
    const char *arg = argv[optind - 1];
    const char *name = long_name(longs, optopt);
    int is_long = !strncmp(arg, "--", 2) && (optopt == 0 || (name &&
                  !strncmp(arg + 2, name, strcspn(arg + 2, "="))));
    int n = (int)strcspn(arg, "=");
    if (n > ARG_SHOWN) n = ARG_SHOWN;
    if (c == ':') {
        if (is_long) cli_usage_error(cmd, "option '%.*s' needs a value", n, arg);
        else cli_usage_error(cmd, "option '-%c' needs a value", optopt);
        return;
    }
    if (is_long && optopt) {
        cli_usage_error(cmd, "option '--%s' takes no value", name);
        return;
    }
    char store[64][32];
    const char *names[65];
    option_names(shorts, longs, store, names, 64);
    if (is_long) {
        cli_unknown_option(cmd, arg, names);
    } else {
        char s[3] = {'-', (char)optopt, 0};
        cli_unknown_option(cmd, s, names);
    }
}

int cli_getopt(const char *cmd, int argc, char **argv, const char *shorts,
               const struct option *longs)
{
    char spec[64];
    snprintf(spec, sizeof spec, ":%s", shorts);
    opterr = 0;
    int c = getopt_long(argc, argv, spec, longs, NULL);
    if (c == '?' || c == ':') {
        option_error(cmd, c, argv, shorts, longs);
        return '?';
    }
    return c;
}

void cli_error_at(const cli_text_at *at, const char *fmt, ...)
{
    const char *name = at->name, *text = at->text;
    size_t len = at->len;
    int line = at->line, col = at->col;
    char msg[512];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    if (line > 0) fprintf(stderr, "%s:%d:%d: %s\n", name, line, col, msg);
    else fprintf(stderr, "%s: %s\n", name, msg);
    /* the line (a window of it when long) and a caret under the column */
    char ex[EXPR_EXCERPT_MAX];
    if (line > 0 && text && expr_excerpt(text, len, line, col, ex, sizeof ex) == 0)
        fputs(ex, stderr);
}
