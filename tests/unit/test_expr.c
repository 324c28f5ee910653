/* The expression language: parsing (precedence, functions against libm,
 * spherical coordinates, named values, comments), errors with exact
 * positions, limits, folding and sharing, tape relocation, and the three
 * evaluators against independent oracles: intervals against dense point
 * samples, gradients against finite differences, pruned tapes against the
 * full tape (bit for bit) on random min/max scenes. */
#include <criterion/criterion.h>
#include <errno.h>
#include <fenv.h>
#include <float.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "expr.h"
#include "expr_impl.h" /* tape layout, for the corruption tests only */

/* ---- helpers ---- */

static expr_tape *compile_ok(const char *src)
{
    expr_tape *t = NULL;
    expr_error e;
    int rc = expr_compile(src, strlen(src), NULL, &t, &e);
    cr_assert_eq(rc, 0, "compile \"%s\": rc %d at %d:%d: %s", src, rc, e.line, e.col, e.msg);
    cr_assert_not_null(t);
    return t;
}

static double eval_src(const char *src, double x, double y, double z)
{
    expr_tape *t = compile_ok(src);
    double v = expr_eval_point(t, x, y, z);
    expr_tape_free(t);
    return v;
}

static uint32_t len_of(const char *src)
{
    expr_tape *t = compile_ok(src);
    uint32_t n = expr_tape_length(t);
    expr_tape_free(t);
    return n;
}

/* Same double, NaNs equal: the evaluators must agree bit for bit. */
static int same_double(double a, double b)
{
    return (a != a && b != b) || !memcmp(&a, &b, sizeof a);
}

static int close_to(double got, double want, double rel)
{
    if (isnan(want)) return isnan(got);
    if (isinf(want)) return got == want;
    return fabs(got - want) <= rel * fmax(1.0, fabs(want));
}

/* xorshift64*: deterministic random numbers for every test. */
static uint64_t rng_state;
/* EXPR_TEST_SEED=n in the environment varies every random test (stress runs). */
static void rng_seed(uint64_t s)
{
    const char *env = getenv("EXPR_TEST_SEED");
    if (env) s += 1000 * strtoull(env, NULL, 10);
    rng_state = s * 0x9e3779b97f4a7c15ull + 1;
}
static uint64_t rng_next(void)
{
    rng_state ^= rng_state >> 12;
    rng_state ^= rng_state << 25;
    rng_state ^= rng_state >> 27;
    return rng_state * 2685821657736338717ull;
}
static double urand(double lo, double hi)
{
    return lo + (hi - lo) * (double)(rng_next() >> 11) * 0x1p-53;
}
static int irand(int n) { return (int)(rng_next() % (uint64_t)n); }

/* ---- precedence, functions, spherical coordinates ---- */

Test(expr_parse, precedence_and_associativity)
{
    const double x = 0.3, y = -0.7, z = 1.1;
    struct { const char *src; double want; } t[] = {
        {"2^3^2", 512},         {"(2^3)^2", 64},       {"-2^2", -4},
        {"(-2)^2", 4},          {"2*3+4", 10},         {"2+3*4", 14},
        {"(2+3)*4", 20},        {"8/4/2", 1},          {"8-3-2", 3},
        {"2^-1", 0.5},          {"-2^-2", -0.25},      {"--2", 2},
        {"+3", 3},              {"2*-3", -6},          {"2^3*2", 16},
        {"2*3^2", 18},          {"-x^2", -(x * x)},    {"1e3+.5", 1000.5},
        {"1.5e-1", 0.15},       {"2.E1", 20},          {"x*y-z/2", x * y - z / 2},
        {"x-y-z", x - y - z},   {"x/y*z", x / y * z},  {"pi", M_PI},
        {"2*pi", 2 * M_PI},     {"-x-y", -x - y},      {"x^y", pow(x, y)},
        {"2^x^2", pow(2, x * x)}, {"(x)", x},          {"((((z))))", z},
    };
    for (size_t i = 0; i < sizeof t / sizeof t[0]; i++) {
        double v = eval_src(t[i].src, x, y, z);
        cr_expect(close_to(v, t[i].want, 1e-15), "%s = %.17g, want %.17g", t[i].src, v,
                  t[i].want);
    }
}

static double f_sin(double x, double y, double z) { (void)y, (void)z; return sin(x); }
static double f_cos(double x, double y, double z) { (void)y, (void)z; return cos(x); }
static double f_tan(double x, double y, double z) { (void)y, (void)z; return tan(x); }
static double f_asin(double x, double y, double z) { (void)y, (void)z; return asin(x / 3); }
static double f_acos(double x, double y, double z) { (void)y, (void)z; return acos(x / 3); }
static double f_atan(double x, double y, double z) { (void)y, (void)z; return atan(x); }
static double f_atan2(double x, double y, double z) { (void)z; return atan2(y, x); }
static double f_exp(double x, double y, double z) { (void)y, (void)z; return exp(x); }
static double f_log(double x, double y, double z) { (void)y, (void)z; return log(x); }
static double f_sqrt(double x, double y, double z) { (void)y, (void)z; return sqrt(x); }
static double f_abs(double x, double y, double z) { (void)y, (void)z; return fabs(x); }
static double f_min(double x, double y, double z) { return fmin(fmin(x, y), z); }
static double f_max(double x, double y, double z) { return fmax(fmax(x, y), z); }
static double f_pow(double x, double y, double z) { (void)z; return pow(x, y); }
static double f_pow3(double x, double y, double z) { (void)y, (void)z; return pow(x, 3); }
static double f_powh(double x, double y, double z) { (void)y, (void)z; return pow(x, 0.5); }
static double f_powm2(double x, double y, double z) { (void)y, (void)z; return pow(x, -2); }
static double f_sq(double x, double y, double z) { (void)y, (void)z; return x * x; }
static double f_blend(double x, double y, double z)
{
    (void)y, (void)z;
    return fabs(x) <= 0.75 ? pow(x * x - 0.5625, 4) / pow(0.75, 8) : 0;
}

Test(expr_parse, functions_match_libm)
{
    struct { const char *src; double (*f)(double, double, double); } t[] = {
        {"sin(x)", f_sin},   {"cos(x)", f_cos},       {"tan(x)", f_tan},
        {"asin(x/3)", f_asin}, {"acos(x/3)", f_acos}, {"atan(x)", f_atan},
        {"atan2(y, x)", f_atan2}, {"exp(x)", f_exp},  {"log(x)", f_log},
        {"sqrt(x)", f_sqrt}, {"abs(x)", f_abs},       {"min(x, y, z)", f_min},
        {"max(x,y,z)", f_max}, {"pow(x, y)", f_pow},  {"x^3", f_pow3},
        {"pow(x, 3)", f_pow3}, {"x^0.5", f_powh},     {"x^-2", f_powm2},
        {"x^2", f_sq},       {"pow(x,2)", f_sq},      {"blend(x, 0.75)", f_blend},
    };
    rng_seed(1);
    for (size_t i = 0; i < sizeof t / sizeof t[0]; i++) {
        expr_tape *tp = compile_ok(t[i].src);
        for (int k = 0; k < 40; k++) {
            double x = urand(-2.5, 2.5), y = urand(-2.5, 2.5), z = urand(-2.5, 2.5);
            if (k == 0) x = 0, y = 0;
            double v = expr_eval_point(tp, x, y, z), w = t[i].f(x, y, z);
            cr_expect(close_to(v, w, 1e-14), "%s at (%g,%g,%g) = %.17g, want %.17g",
                      t[i].src, x, y, z, v, w);
        }
        expr_tape_free(tp);
    }
}

Test(expr_parse, nan_propagates_through_min_max_blend)
{
    /* F is undefined where an operand is: what the interval evaluator assumes */
    cr_expect(isnan(eval_src("min(sqrt(x), 1)", -1, 0, 0)));
    cr_expect(isnan(eval_src("min(1, sqrt(x))", -1, 0, 0)));
    cr_expect(isnan(eval_src("max(sqrt(x), 1, y)", -1, 0, 0)));
    cr_expect(isnan(eval_src("blend(sqrt(x), 1)", -1, 0, 0)));
    cr_expect(isnan(eval_src("blend(log(x), 0.5)", -1, 0, 0)));
    cr_expect_eq(eval_src("min(sqrt(x), 1)", 4, 0, 0), 1.0);
    cr_expect_eq(eval_src("blend(x, 1)", 2, 0, 0), 0.0);
}

Test(expr_parse, spherical_coordinates)
{
    expr_tape *tr = compile_ok("r"), *tt = compile_ok("theta"), *tp = compile_ok("phi");
    rng_seed(2);
    for (int k = 0; k < 200; k++) {
        double x = urand(-3, 3), y = urand(-3, 3), z = urand(-3, 3);
        double r = sqrt(x * x + y * y + z * z);
        cr_expect(close_to(expr_eval_point(tr, x, y, z), hypot(hypot(x, y), z), 1e-15));
        cr_expect(close_to(expr_eval_point(tt, x, y, z), atan2(y, x), 1e-15));
        cr_expect(close_to(expr_eval_point(tp, x, y, z), acos(z / r), 1e-12));
    }
    /* on the axis and at the origin: defined, no NaN */
    cr_expect_eq(expr_eval_point(tp, 0, 0, 2), 0.0);
    cr_expect_eq(expr_eval_point(tp, 0, 0, -2), M_PI);
    cr_expect_eq(expr_eval_point(tp, 0, 0, 0), 0.0);
    cr_expect_eq(expr_eval_point(tt, 0, 0, 0), 0.0);
    cr_expect_eq(expr_eval_point(tt, 0, 2, 0), M_PI / 2);
    cr_expect_eq(expr_eval_point(tr, 0, 0, 0), 0.0);
    expr_tape_free(tr);
    expr_tape_free(tt);
    expr_tape_free(tp);
}

Test(expr_parse, named_values_and_comments)
{
    const double x = 0.4, y = -0.2, z = 0.9;
    double want = sqrt(x * x + y * y + z * z) - 1;
    cr_expect(close_to(eval_src("a = x^2 + y^2; b = a + z^2; sqrt(b) - 1", x, y, z), want, 1e-15));
    const char *src = "# sphere, written out\n"
                      "  a = x^2 + y^2;   # the xy part\n"
                      "b=a+z^2;\n"
                      "\tsqrt( b )\r\n - 1 ; # trailing semicolon allowed\n";
    cr_expect(close_to(eval_src(src, x, y, z), want, 1e-15));
    cr_expect(close_to(eval_src("R = 0.5; c = R*2; c + x", x, y, z), 1 + x, 1e-15));
    cr_expect(close_to(eval_src("_a1 = 2; A1 = 3; _a1 * A1", x, y, z), 6, 0));
    cr_expect(close_to(eval_src("a=x; b=a; c=b; c*c", x, y, z), x * x, 0));
    /* the Scene 1 style of docs/expressions.md */
    const char *s1 = "R = 0.5;\n"
                     "a = blend(sqrt((x-0.3)^2 + y^2 + z^2), R);\n"
                     "b = blend(sqrt((x+0.3)^2 + y^2 + z^2), R);\n"
                     "0.25 - (a + b)\n";
    double da = sqrt(0.01 + y * y + z * z), db = sqrt(0.49 + y * y + z * z);
    double ga = da <= 0.5 ? pow(da * da - 0.25, 4) / pow(0.5, 8) : 0;
    double gb = db <= 0.5 ? pow(db * db - 0.25, 4) / pow(0.5, 8) : 0;
    cr_expect(close_to(eval_src(s1, x, y, z), 0.25 - (ga + gb), 1e-14));
    cr_expect(close_to(eval_src(s1, 0.3, 0.1, 0), 0.25 - pow(0.01 - 0.25, 4) / pow(0.5, 8), 1e-14));
}

/* ---- errors ---- */

typedef struct {
    const char *src;
    size_t len; /* 0: strlen */
    int rc, line, col;
    const char *msg;
} bad_case;

static void check_bad(const bad_case *b, const expr_limits *lim)
{
    expr_tape *t = (expr_tape *)1;
    expr_error e;
    size_t len = b->len ? b->len : strlen(b->src);
    int rc = expr_compile(b->src, len, lim, &t, &e);
    cr_expect_eq(rc, b->rc, "\"%s\": rc %d, want %d (%s)", b->src, rc, b->rc, e.msg);
    cr_expect_null(t, "\"%s\": *out not cleared", b->src);
    cr_expect(e.line == b->line && e.col == b->col, "\"%s\": at %d:%d, want %d:%d (%s)",
              b->src, e.line, e.col, b->line, b->col, e.msg);
    cr_expect_str_eq(e.msg, b->msg, "\"%s\"", b->src);
}

Test(expr_errors, exact_positions_and_messages)
{
    const int E = -EINVAL;
    bad_case t[] = {
        {"sinn(x)", 0, E, 1, 1, "unknown function 'sinn'"},
        {"x + foo", 0, E, 1, 5, "'foo' is not defined"},
        {"sin(x", 0, E, 1, 6, "expected ')' after argument list"},
        {"max(x, y z)", 0, E, 1, 10, "expected ')' after argument list"},
        {"(x + 1", 0, E, 1, 7, "expected ')' to close the '(' at 1:1"},
        {"x + 1)", 0, E, 1, 6, "unexpected ')' after the expression"},
        {"x y", 0, E, 1, 3, "unexpected 'y' after the expression"},
        {"x +\n  1.2.3", 0, E, 2, 3, "malformed number '1.2.3'"},
        {"1e+", 0, E, 1, 1, "malformed number '1e+'"},
        {"3 * 2x", 0, E, 1, 5, "malformed number '2x'"},
        {"1e999", 0, E, 1, 1, "number out of range '1e999'"},
        {"a = 1;\na = 2;\na", 0, E, 2, 1, "'a' is already defined at 1:1"},
        {"b = a + 1; a = 1; b", 0, E, 1, 5, "'a' is not defined"},
        {"a = a + 1; a", 0, E, 1, 5, "'a' is not defined"},
        {"atan2(x)", 0, E, 1, 1, "atan2 takes 2 arguments"},
        {"1 + sin(x, y)", 0, E, 1, 5, "sin takes 1 argument"},
        {"min(x)", 0, E, 1, 1, "min takes at least 2 arguments"},
        {"cos()", 0, E, 1, 1, "cos takes 1 argument"},
        {"", 0, E, 1, 1, "empty expression"},
        {"  # only a comment\n\n", 0, E, 3, 1, "empty expression"},
        {"x\0+1", 4, E, 1, 2, "NUL byte in expression"},
        {"a = 1;\n  b = \0", 14, E, 2, 7, "NUL byte in expression"},
        {"sin = 2; sin", 0, E, 1, 1, "cannot redefine function 'sin'"},
        {"x = 1; x", 0, E, 1, 1, "cannot redefine variable 'x'"},
        {"y=2;\n theta = 1; 2", 0, E, 1, 1, "cannot redefine variable 'y'"},
        {"pi = 3; pi", 0, E, 1, 1, "cannot redefine constant 'pi'"},
        {"a = 1", 0, E, 1, 6, "expected ';' after the definition of 'a', found end of input"},
        {"a = 1;", 0, E, 1, 7, "expected an expression after the definitions"},
        {"x + * 2", 0, E, 1, 5, "expected an expression, found '*'"},
        {"x +", 0, E, 1, 4, "expected an expression, found end of input"},
        {"x(2)", 0, E, 1, 1, "'x' is not a function"},
        {"sin + 1", 0, E, 1, 1, "expected '(' after function name 'sin'"},
        {"x $ y", 0, E, 1, 3, "unexpected character '$'"},
        {"x +\r\n\t)", 0, E, 2, 2, "expected an expression, found ')'"},
        {"blend(x, y)", 0, E, 1, 10, "the radius of blend must be a positive finite constant"},
        {"blend(x, 1 - 2)", 0, E, 1, 12, "the radius of blend must be a positive finite constant"},
        {"x + \xce\xb8", 0, E, 1, 5, "unexpected byte 0xce (expressions are ASCII)"},
    };
    for (size_t i = 0; i < sizeof t / sizeof t[0]; i++) check_bad(&t[i], NULL);
}

Test(expr_errors, err_may_be_null)
{
    expr_tape *t;
    cr_expect_eq(expr_compile("sin(", 4, NULL, &t, NULL), -EINVAL);
    cr_expect_null(t);
}

/* ---- where an error is: the excerpt ---- */

static int compile_rc(const char *src, const expr_limits *lim, expr_error *e);

/* The excerpt's two lines, checked: each at most 2 + 3 + 80 + 3 characters,
 * and the caret under the character at col (or just past the line's end).
 * Returns the shown line (without its indent) in text. */
static void excerpt_ok(const char *src, int line, int col, char *text, size_t n)
{
    char buf[EXPR_EXCERPT_MAX];
    cr_assert_eq(expr_excerpt(src, strlen(src), line, col, buf, sizeof buf), 0);
    char *nl = strchr(buf, '\n');
    cr_assert_not_null(nl);
    size_t l1 = (size_t)(nl - buf), l2 = strlen(nl + 1) - 1;
    cr_expect_leq(l1, 88, "%s", buf);
    cr_expect_eq(nl[1 + l2], '\n');
    cr_expect_eq(nl[l2], '^', "%s", buf);
    for (size_t i = 0; i + 1 < l2; i++) cr_expect_eq(nl[1 + i], ' ');
    /* the caret's column in the first line shows the source byte at col */
    const char *ls = src;
    for (int k = 1; k < line; k++) ls = strchr(ls, '\n') + 1;
    size_t ll = strcspn(ls, "\n"), c = (size_t)col - 1;
    char want = ls[c] == '\t' ? ' ' : ls[c] < 0x20 || ls[c] > 0x7e ? '?' : ls[c];
    if (c < ll) cr_expect_eq(buf[l2 - 1], want, "col %d: %s", col, buf);
    else cr_expect_eq(l2 - 1, l1, "past the end: %s", buf);
    snprintf(text, n, "%.*s", (int)l1 - 2, buf + 2);
}

Test(expr_errors, excerpt_windows_long_lines)
{
    char text[128];
    /* a short line is shown whole */
    excerpt_ok("x + y * (z", 1, 11, text, sizeof text);
    cr_expect_str_eq(text, "x + y * (z");
    excerpt_ok("a = 1;\n\tb = sinn(x);\nb", 2, 6, text, sizeof text);
    cr_expect_str_eq(text, " b = sinn(x);");
    /* a line of 8000 bytes: a window around the column, cut at both ends */
    size_t n = 8000;
    char *src = malloc(n + 1);
    for (size_t i = 0; i < n; i++) src[i] = "x+y*"[i % 4];
    src[n] = 0;
    src[5003] = '$';
    excerpt_ok(src, 1, 5004, text, sizeof text);
    cr_expect_eq(strncmp(text, "...", 3), 0, "%s", text);
    cr_expect_eq(strcmp(text + strlen(text) - 3, "..."), 0, "%s", text);
    cr_expect_eq(strlen(text), 86);
    cr_expect_not_null(strchr(text, '$'));
    /* near the start: cut at the end only; near the end: at the start only */
    for (int col = 1; col <= 41; col += 10) {
        excerpt_ok(src, 1, col, text, sizeof text);
        cr_expect_neq(strncmp(text, "...", 3), 0, "col %d: %s", col, text);
    }
    for (int col = 7961; col <= 8001; col += 8) {
        excerpt_ok(src, 1, col, text, sizeof text);
        cr_expect_eq(strncmp(text, "...", 3), 0, "col %d: %s", col, text);
        cr_expect_neq(strcmp(text + strlen(text) - 3, "..."), 0, "col %d: %s", col, text);
    }
    /* every column of a long line lands its caret right */
    for (int col = 1; col <= 8001; col += 97) excerpt_ok(src, 1, col, text, sizeof text);
    /* the line of the error, not the first one; control bytes are '?' */
    src[100] = '\n';
    src[130] = '\x01';
    excerpt_ok(src, 2, 30, text, sizeof text);
    cr_expect_eq(text[29], '?', "%s", text);
    free(src);
    /* no such line, no column */
    char buf[EXPR_EXCERPT_MAX];
    cr_expect_eq(expr_excerpt("x", 1, 2, 1, buf, sizeof buf), -EINVAL);
    cr_expect_eq(expr_excerpt("x", 1, 1, 0, buf, sizeof buf), -EINVAL);
    cr_expect_str_eq(buf, "");
}

Test(expr_errors, a_long_line_error_is_short)
{
    /* the parser's own messages stay short whatever the source: names and
     * numbers are cut at 40 bytes */
    size_t n = 9000;
    char *src = malloc(n + 16);
    memset(src, 'a', n);
    strcpy(src + n, "(x)");
    expr_error e;
    cr_expect_eq(compile_rc(src, NULL, &e), -EINVAL);
    cr_expect_leq(strlen(e.msg), 80, "%s", e.msg);
    memcpy(src + n, " + 1", 5);
    memset(src, '1', n);
    src[1] = 'x';
    cr_expect_eq(compile_rc(src, NULL, &e), -EINVAL);
    cr_expect_leq(strlen(e.msg), 80, "%s", e.msg);
    free(src);
}

/* ---- limits ---- */

static char *repeat3(const char *a, int n, const char *mid, const char *b)
{
    size_t la = strlen(a), lm = strlen(mid), lb = strlen(b);
    char *s = malloc(n * (la + lb) + lm + 1), *p = s;
    for (int i = 0; i < n; i++, p += la) memcpy(p, a, la);
    memcpy(p, mid, lm);
    p += lm;
    for (int i = 0; i < n; i++, p += lb) memcpy(p, b, lb);
    *p = 0;
    return s;
}

static int compile_rc(const char *src, const expr_limits *lim, expr_error *e)
{
    expr_tape *t = NULL;
    int rc = expr_compile(src, strlen(src), lim, &t, e);
    expr_tape_free(t);
    return rc;
}

Test(expr_limits, source_length)
{
    expr_limits lim = {.max_source_bytes = 10};
    bad_case b = {"x+x+x+x+x+x", 0, -E2BIG, 0, 0, "expression is too long (11 bytes, limit 10)"};
    check_bad(&b, &lim);
    expr_error e;
    cr_expect_eq(compile_rc("x+x+x+x+x", &lim, &e), 0);
    /* the default: 64 KiB */
    char *big = repeat3("x+", 32768, "x", "");
    cr_expect_eq(compile_rc(big, NULL, &e), -E2BIG);
    cr_expect_str_eq(e.msg, "expression is too long (65537 bytes, limit 65536)");
    free(big);
}

Test(expr_limits, deep_nesting_does_not_crash)
{
    expr_error e;
    expr_limits lim = {.max_source_bytes = 1u << 20};
    const char *opens[] = {"(", "-", "sin(", "x^", "-(", "min(x,"};
    const char *closes[] = {")", "", ")", "", ")", ")"};
    for (int i = 0; i < 6; i++) {
        char *s = repeat3(opens[i], 100000, "x", closes[i]);
        cr_expect_eq(compile_rc(s, &lim, &e), -E2BIG, "opener %s", opens[i]);
        cr_expect_str_eq(e.msg, "expression nests too deeply (limit 256 levels)");
        cr_expect_eq(e.line, 1);
        free(s);
    }
    /* a huge max_depth is lowered to the cap, which keeps the stack small */
    lim.max_depth = 1u << 30;
    char *s2 = repeat3("(", 2000, "x", ")");
    cr_expect_eq(compile_rc(s2, &lim, &e), -E2BIG);
    cr_expect_str_eq(e.msg, "expression nests too deeply (limit 1024 levels)");
    free(s2);
    /* exactly at the limit: 4 parentheses need 5 levels */
    lim.max_depth = 5;
    cr_expect_eq(compile_rc("((((x))))", &lim, &e), 0);
    cr_expect_eq(compile_rc("(((((x)))))", &lim, &e), -E2BIG);
    cr_expect_eq(e.col, 6);
    /* a long flat chain is one level (the compiler loops along it) */
    char *chain = repeat3("x+", 300, "x", "");
    cr_expect_eq(compile_rc(chain, NULL, &e), 0, "%s", e.msg);
    free(chain);
    chain = repeat3("x*", 200, "x", "");
    cr_expect_eq(compile_rc(chain, NULL, &e), 0);
    free(chain);
    /* ... but many arguments of min are one level */
    char *args = repeat3("x,", 5000, "x", "");
    char *m = malloc(strlen(args) + 8);
    sprintf(m, "min(%s)", args);
    cr_expect_eq(compile_rc(m, NULL, &e), 0, "%s", e.msg);
    free(args);
    free(m);
}

/* "c0*x^2+c1*x^2+...": n terms with coefficients 0.00001 .. (as a program
 * writes a polynomial), and the same sum folded left in C. */
static char *coef_sum(int n, double x, double *want)
{
    char *s = malloc((size_t)n * 24 + 1), *p = s;
    double acc = 0;
    for (int i = 0; i < n; i++) {
        char c[16];
        snprintf(c, sizeof c, "0.%05d", i + 1);
        p += sprintf(p, "%s%s*x^2", i ? "+" : "", c);
        double t = strtod(c, NULL) * (x * x);
        acc = i ? acc + t : t;
    }
    *want = acc;
    return s;
}

Test(expr_limits, flat_chains_are_not_nesting)
{
    expr_error e;
    expr_limits big = {.max_source_bytes = 1u << 20};
    /* 10,000 terms: compiles with the default depth, evaluates as the left
     * fold it is, bit for bit, with every evaluator */
    double x = 0.3, want;
    char *src = coef_sum(10000, x, &want);
    expr_tape *t = NULL;
    cr_assert_eq(expr_compile(src, strlen(src), &big, &t, &e), 0, "%d:%d: %s", e.line, e.col,
                 e.msg);
    /* x^2 once, a product per term, a sum per term but the first */
    cr_expect_eq(expr_tape_length(t), 1 + 10000 + 9999);
    cr_expect(same_double(expr_eval_point(t, x, 0, 0), want), "%.17g vs %.17g",
              expr_eval_point(t, x, 0, 0), want);
    ival v = expr_eval_ival(t, ival_point(x), ival_point(0), ival_point(0));
    cr_expect(v.lo <= want && want <= v.hi, "[%.17g, %.17g] vs %.17g", v.lo, v.hi, want);
    expr_vm *vm;
    cr_assert_eq(expr_vm_new(t, 4, &vm), 0);
    double g[3];
    cr_expect(same_double(expr_vm_grad(vm, 0, x, 0, 0, g), want));
    cr_expect(g[0] > 0 && g[1] == 0 && g[2] == 0);
    expr_vm_free(vm);
    expr_tape_free(t);
    free(src);

    /* a sum under min: pruning drops the whole chain where the other side wins */
    src = coef_sum(10000, x, &want);
    char *m = malloc(strlen(src) + 32);
    sprintf(m, "min(%s, x - 10)", src);
    cr_assert_eq(expr_compile(m, strlen(m), &big, &t, &e), 0, "%s", e.msg);
    cr_assert_eq(expr_vm_new(t, 4, &vm), 0);
    ival b = ival_make(-1, 1);
    expr_vm_ival(vm, 0, b, b, b);
    expr_vm_prune(vm, 0);
    cr_expect_eq(expr_vm_length(vm, 1), 1, "pruned to x - 10: %u", expr_vm_length(vm, 1));
    expr_vm_free(vm);
    expr_tape_free(t);
    free(m);
    free(src);

    /* products, quotients, differences and their mixes are chains too */
    const char *ops[] = {"x*", "x/", "x-", "x*y+", "x^2*y-", "-x*2+"};
    for (int i = 0; i < 6; i++) {
        char *c = repeat3(ops[i], 5000, "x", "");
        cr_expect_eq(compile_rc(c, &big, &e), 0, "%s...: %s", ops[i], e.msg);
        free(c);
    }
    /* a chain inside 255 parentheses still fits the default 256 levels */
    char *sum = repeat3("x+", 3000, "x", "");
    char *in = repeat3("(", 255, sum, ")");
    cr_expect_eq(compile_rc(in, &big, &e), 0, "%s", e.msg);
    free(in);
    free(sum);
}

Test(expr_limits, real_nesting_counts)
{
    expr_error e;
    expr_limits big = {.max_source_bytes = 1u << 20};
    /* 300 nested parentheses, calls, signs, powers: the depth error */
    const char *opens[] = {"(", "sin(", "-", "x^", "(x+", "min(x,", "1+(", "2*sin("};
    const char *closes[] = {")", ")", "", "", ")", ")", ")", ")"};
    for (int i = 0; i < 8; i++) {
        char *s = repeat3(opens[i], 300, "x", closes[i]);
        cr_expect_eq(compile_rc(s, &big, &e), -E2BIG, "opener %s", opens[i]);
        cr_expect_str_eq(e.msg, "expression nests too deeply (limit 256 levels)");
        free(s);
    }
    /* parentheses around the right operands nest: a+(b+(c+...)) */
    char *r = repeat3("x+(", 300, "x", ")");
    cr_expect_eq(compile_rc(r, &big, &e), -E2BIG);
    free(r);
    /* ... and the limit is exact: a chain is one level above the terms it
     * joins, whatever its length */
    expr_limits three = {.max_depth = 3};
    cr_expect_eq(compile_rc("((x+x+x+x*x*x))", &three, &e), 0, "%s", e.msg);
    cr_expect_eq(compile_rc("(((x+x)))", &three, &e), -E2BIG);
    cr_expect_eq(compile_rc("x*x*x/x*sin(x)", &three, &e), 0, "%s", e.msg);
    cr_expect_eq(compile_rc("x*x*x/x*sin(x+x)", &three, &e), -E2BIG);
    cr_expect_eq(compile_rc("sin(sin(x))", &three, &e), 0, "%s", e.msg);
    cr_expect_eq(compile_rc("sin(sin(x+x))", &three, &e), -E2BIG);
    cr_expect_str_eq(e.msg, "expression nests too deeply (limit 3 levels)");
}

Test(expr_limits, node_count)
{
    expr_limits lim = {.max_nodes = 10};
    bad_case b = {"x+x+x+x+x+x", 0, -E2BIG, 1, 10, "expression is too large (more than 10 syntax nodes)"};
    check_bad(&b, &lim);
    expr_error e;
    cr_expect_eq(compile_rc("x+x+x+x+x", &lim, &e), 0);
    /* named values count too */
    lim.max_nodes = 12;
    cr_expect_eq(compile_rc("a=x+x; b=a+a; c=b+b; c+c", &lim, &e), 0);
    cr_expect_eq(compile_rc("a=x+x; b=a+a; c=b+b; d=c+c; d+d", &lim, &e), -E2BIG);
}

/* ---- folding and sharing ---- */

Test(expr_compile, common_subexpressions_are_shared)
{
    cr_expect_eq(len_of("(x+1)*(x+1)"), 2);
    cr_expect_eq(len_of("(x+1)*(1+x)"), 2);
    cr_expect_eq(len_of("(x+1)*(x+2)"), 3);
    cr_expect_lt(len_of("(x+1)*(x+1)"), len_of("(x+1)*(x+2)"));
    /* sin, cos, mul; then mul(a,a), add, div, add */
    cr_expect_eq(len_of("a = sin(x)*cos(y); a + a*a + a/2"), 7);
    cr_expect_eq(len_of("sin(x)*cos(y) + (sin(x)*cos(y))*(sin(x)*cos(y)) + sin(x)*cos(y)/2"), 7);
    /* unused named values leave no code */
    cr_expect_eq(len_of("a = sin(x); b = cos(y); b"), 1);
    /* sphere: sqr x3, add x2, sqrt, sub */
    cr_expect_eq(len_of("sqrt(x^2+y^2+z^2)-0.8"), 7);
    cr_expect_eq(len_of("a = x^2 + y^2; b = a + z^2; sqrt(b) - 1"), 7);
}

Test(expr_compile, constants_fold_to_an_empty_tape)
{
    const char *src = "k = 2*pi; sin(k/8)^2 + cos(pi/4)^2 - 2*3 + exp(log(2))";
    expr_tape *t = compile_ok(src);
    cr_expect_eq(expr_tape_length(t), 0);
    double want = pow(sin(2 * M_PI / 8), 2) + pow(cos(M_PI / 4), 2) - 6 + exp(log(2));
    cr_expect(close_to(expr_eval_point(t, 1, 2, 3), want, 1e-15));
    /* the interval of a folded constant encloses its exact value */
    ival v = expr_eval_ival(t, ival_make(0, 1), ival_make(0, 1), ival_make(0, 1));
    cr_expect(v.lo <= want && want <= v.hi && v.hi - v.lo < 1e-13, "[%.17g, %.17g]", v.lo, v.hi);
    expr_tape_free(t);
    /* pi is enclosed: the double M_PI is below the real pi */
    t = compile_ok("pi");
    v = expr_eval_ival(t, ival_point(0), ival_point(0), ival_point(0));
    cr_expect(v.lo == M_PI && v.hi > M_PI);
    expr_tape_free(t);
    /* non-finite folded constants are kept */
    t = compile_ok("1/0 + x*0");
    cr_expect(isinf(expr_eval_point(t, 1, 1, 1)));
    expr_tape_free(t);
    cr_expect(isnan(eval_src("0/0", 0, 0, 0)));
}

Test(expr_compile, integer_powers)
{
    cr_expect_eq(len_of("x^2"), 1);
    cr_expect_eq(len_of("x^3"), 1);
    cr_expect_eq(len_of("x^1"), 0);
    cr_expect_eq(len_of("x^0"), 0);
    cr_expect_eq(len_of("x^(1+1)"), 1);
    cr_expect_eq(len_of("x^2.5"), 1);
    cr_expect_eq(eval_src("x^0", NAN, 0, 0), 1.0);
    cr_expect_eq(eval_src("x^1", -3.5, 0, 0), -3.5);
    cr_expect_eq(eval_src("x^3", -2, 0, 0), -8.0);
    cr_expect_eq(eval_src("x^-3", -2, 0, 0), -0.125);
    cr_expect(isnan(eval_src("x^2.5", -2, 0, 0)));
    cr_expect_eq(eval_src("x^40000", 1, 0, 0), 1.0); /* beyond int16: stays pow */
    /* an integer power of a negative box is exact in sign */
    expr_tape *t = compile_ok("x^3");
    ival v = expr_eval_ival(t, ival_make(-2, -1), ival_point(0), ival_point(0));
    cr_expect(v.lo <= -8 && v.hi >= -1 && v.hi < 0);
    expr_tape_free(t);
}

Test(expr_compile, registers_are_reused)
{
    /* 200 independent terms summed: only a few scratch registers live */
    char *s = malloc(200 * 32 + 8), *p = s;
    for (int i = 0; i < 100; i++) p += sprintf(p, "%ssin(x*%d)", i ? "+" : "", i + 2);
    expr_tape *t = compile_ok(s);
    const expr_tape *h = t;
    cr_expect_lt(h->nregs - EXPR_NVARS - h->nconst, 4u, "scratch registers %u",
                 h->nregs - EXPR_NVARS - h->nconst);
    expr_tape_free(t);
    free(s);
}

/* ---- relocation and validation ---- */

Test(expr_tape, memcpy_relocation)
{
    const char *src = "a = min(sqrt((x-0.5)^2+y^2+z^2)-0.3, sqrt((x+0.5)^2+y^2+z^2)-0.3);"
                      "max(a, -z) + 0.1*sin(3*theta)*phi";
    expr_tape *t = compile_ok(src), *ref = compile_ok(src);
    size_t n = expr_tape_bytes(t);
    cr_assert_gt(n, sizeof(struct expr_tape));
    /* an odd offset inside a bigger block, then the original is gone */
    char *block = aligned_alloc(64, (n + 128 + 63) / 64 * 64);
    void *copy = block + 40;
    memcpy(copy, t, n);
    memset(t, 0xa5, n);
    expr_tape_free(t);
    cr_assert_eq(expr_tape_validate(copy, n), 0);
    const expr_tape *c = copy;
    cr_expect_eq(expr_tape_length(c), expr_tape_length(ref));
    rng_seed(3);
    expr_vm *vm;
    cr_assert_eq(expr_vm_new(c, 3, &vm), 0);
    for (int k = 0; k < 50; k++) {
        double x = urand(-1, 1), y = urand(-1, 1), z = urand(-1, 1), g1[3], g2[3];
        cr_expect(same_double(expr_vm_point(vm, 0, x, y, z), expr_eval_point(ref, x, y, z)));
        double v1 = expr_vm_grad(vm, 0, x, y, z, g1);
        expr_vm *vr;
        cr_assert_eq(expr_vm_new(ref, 0, &vr), 0);
        double v2 = expr_vm_grad(vr, 0, x, y, z, g2);
        expr_vm_free(vr);
        cr_expect(same_double(v1, v2) && !memcmp(g1, g2, sizeof g1));
        ival X = ival_make(x, x + 0.1), Y = ival_make(y, y + 0.2), Z = ival_make(z, z + 0.05);
        ival a = expr_vm_ival(vm, 0, X, Y, Z), b = expr_eval_ival(ref, X, Y, Z);
        cr_expect(same_double(a.lo, b.lo) && same_double(a.hi, b.hi));
    }
    expr_vm_free(vm);
    free(block);
    expr_tape_free(ref);
}

Test(expr_tape, validate_rejects_corruption)
{
    expr_tape *t = compile_ok("min(x*y, sin(z)) + 2");
    size_t n = expr_tape_bytes(t);
    cr_expect_eq(expr_tape_validate(t, n), 0);
    cr_expect_eq(expr_tape_validate(t, n - 1), -EINVAL);
    cr_expect_eq(expr_tape_validate(t, 8), -EINVAL);
    expr_tape *c = malloc(n);
    expr_insn *code;
    struct { int field; uint16_t v; } bad[] = {
        {0, 200},            /* op out of range */
        {1, 0},              /* writes x */
        {1, 60000},          /* register out of range */
        {2, 60000},          /* reads out of range */
    };
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        memcpy(c, t, n);
        code = (expr_insn *)expr_tape_code(c);
        if (bad[i].field == 0) code[0].op = (uint8_t)bad[i].v;
        if (bad[i].field == 1) code[0].out = bad[i].v;
        if (bad[i].field == 2) code[1].a = bad[i].v;
        cr_expect_eq(expr_tape_validate(c, n), -EINVAL, "case %zu", i);
        expr_vm *vm = NULL;
        cr_expect_eq(expr_vm_new(c, 0, &vm), -EINVAL);
        cr_expect_null(vm);
    }
    /* reading a scratch register before anything wrote it */
    memcpy(c, t, n);
    code = (expr_insn *)expr_tape_code(c);
    code[0].a = (uint16_t)(c->nregs - 1);
    cr_expect_eq(expr_tape_validate(c, n), -EINVAL);
    memcpy(c, t, n);
    c->magic ^= 1;
    cr_expect_eq(expr_tape_validate(c, n), -EINVAL);
    memcpy(c, t, n);
    c->len += 1;
    cr_expect_eq(expr_tape_validate(c, n), -EINVAL);
    expr_vm *vm;
    cr_expect_eq(expr_vm_new(t, 33, &vm), -EINVAL);
    cr_expect_eq(expr_vm_new(t, -1, &vm), -EINVAL);
    free(c);
    expr_tape_free(t);
}

/* ---- random expressions, as source text ---- */

typedef struct {
    char *buf;
    size_t len, cap;
    int smooth; /* only differentiable functions (gradient test) */
} gen;

static void put(gen *g, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void put(gen *g, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    int n = vsnprintf(g->buf + g->len, g->cap - g->len, fmt, ap);
    va_end(ap);
    cr_assert(n >= 0 && g->len + (size_t)n < g->cap, "generator buffer");
    g->len += (size_t)n;
}

static void gen_expr(gen *g, int depth);

static void gen_leaf(gen *g)
{
    static const char *const leaves[] = {"x", "y", "z", "r", "theta", "phi", "pi", "x", "y", "z"};
    if (irand(3) == 0) put(g, "%.2f", urand(-3, 3));
    else put(g, "%s", leaves[irand(10)]);
}

static void gen_unary(gen *g, int depth)
{
    static const char *const any[] = {"sin", "cos", "tan", "asin", "acos", "atan", "exp",
                                      "log", "sqrt", "abs"};
    static const char *const smooth[] = {"sin", "cos", "atan", "exp"};
    int k = irand(g->smooth ? 7 : 14);
    if (k < 4 && g->smooth) {
        put(g, "%s(", smooth[k]);
        gen_expr(g, depth - 1);
        put(g, ")");
        return;
    }
    if (k >= 10 || (g->smooth && k >= 4)) {
        static const char *const pw[] = {"2", "3", "-1", "0.5", "(-2)", "4"};
        put(g, "(");
        gen_expr(g, depth - 1);
        put(g, ")^%s", pw[irand(g->smooth ? 3 : 6)]);
        return;
    }
    put(g, k == 9 && irand(2) ? "-(" : "%s(", any[k]);
    gen_expr(g, depth - 1);
    put(g, ")");
}

static void gen_binary(gen *g, int depth)
{
    static const char *const ops[] = {"+", "-", "*", "/"};
    int k = irand(g->smooth ? 5 : 9);
    if (k < 4) {
        put(g, "(");
        gen_expr(g, depth - 1);
        put(g, " %s ", ops[k]);
        gen_expr(g, depth - 1);
        put(g, ")");
        return;
    }
    static const char *const fn[] = {"atan2", "min", "max", "pow", "blend"};
    k = g->smooth ? 0 : k - 4;
    put(g, "%s(", fn[k]);
    gen_expr(g, depth - 1);
    put(g, ", ");
    if (k == 4) put(g, "%.2f", urand(0.1, 2));
    else gen_expr(g, depth - 1);
    if ((k == 1 || k == 2) && irand(2)) {
        put(g, ", ");
        gen_expr(g, depth - 1);
    }
    put(g, ")");
}

static void gen_expr(gen *g, int depth)
{
    int k = depth <= 0 ? 0 : irand(5);
    if (k == 0) gen_leaf(g);
    else if (k <= 2) gen_unary(g, depth);
    else gen_binary(g, depth);
}

static char *random_source(int depth, int smooth)
{
    gen g = {malloc(1 << 16), 0, 1 << 16, smooth};
    if (irand(3) == 0) {
        put(&g, "t = ");
        gen_expr(&g, depth - 1);
        put(&g, "; ");
        gen_expr(&g, depth - 1);
        put(&g, " + t*");
        gen_expr(&g, 1);
    } else {
        gen_expr(&g, depth);
    }
    return g.buf;
}

/* ---- interval soundness against the point evaluator ---- */

static void random_box(ival box[3], double maxw)
{
    for (int j = 0; j < 3; j++) {
        double c = urand(-2, 2), w = maxw * pow(10, urand(-3, 0));
        box[j] = ival_make(c - w, c + w);
        if (irand(8) == 0) box[j] = ival_make(0, w); /* touch an axis */
        if (irand(16) == 0) box[j] = ival_make(-w, w); /* straddle it */
    }
}

static void sample(const ival box[3], int k, double p[3])
{
    for (int j = 0; j < 3; j++) {
        double u = k < 8 ? (double)((k >> j) & 1) : urand(0, 1);
        p[j] = fmin(fmax(box[j].lo + u * (box[j].hi - box[j].lo), box[j].lo), box[j].hi);
    }
}

/* v from a point in the box must lie in I (NaN points and NaN intervals say
 * nothing). */
static int encloses(ival I, double v)
{
    return isnan(v) || ival_is_nan(I) || (I.lo <= v && v <= I.hi);
}

/* F at p, or NaN where the evaluation hit a pole exactly (x/0, log(0)):
 * there the sign of the infinity comes from the sign of a zero, which
 * intervals (sets of reals) do not carry, e.g. 1/min(x, 0) at x > 0 is
 * +inf while [-1, 0] gives 1/[-1, 0] = [-inf, -1].  Like NaN points, such
 * points are outside F's domain and never on the surface F = 0. */
static double defined_point(expr_vm *vm, int d, const double p[3])
{
    feclearexcept(FE_DIVBYZERO);
    double v = expr_vm_point(vm, d, p[0], p[1], p[2]);
    return fetestexcept(FE_DIVBYZERO) ? NAN : v;
}

Test(expr_eval, interval_encloses_point_samples)
{
    rng_seed(4);
    int checked = 0;
    for (int e = 0; e < 300; e++) {
        char *src = random_source(2 + e % 4, 0);
        expr_tape *t = compile_ok(src);
        expr_vm *vm;
        cr_assert_eq(expr_vm_new(t, 0, &vm), 0);
        for (int b = 0; b < 8; b++) {
            ival box[3];
            random_box(box, 1.0);
            ival I = expr_vm_ival(vm, 0, box[0], box[1], box[2]);
            cr_assert(ival_is_nan(I) || I.lo <= I.hi, "%s: [%g, %g]", src, I.lo, I.hi);
            for (int k = 0; k < 48; k++) {
                double p[3];
                sample(box, k, p);
                double v = defined_point(vm, 0, p);
                checked += !isnan(v) && !ival_is_nan(I);
                cr_assert(encloses(I, v),
                          "%s\n box [%.17g,%.17g]x[%.17g,%.17g]x[%.17g,%.17g]\n"
                          " F(%.17g,%.17g,%.17g) = %.17g not in [%.17g, %.17g]",
                          src, box[0].lo, box[0].hi, box[1].lo, box[1].hi, box[2].lo,
                          box[2].hi, p[0], p[1], p[2], v, I.lo, I.hi);
            }
        }
        expr_vm_free(vm);
        expr_tape_free(t);
        free(src);
    }
    cr_expect_gt(checked, 300 * 8 * 48 / 4, "too few informative samples: %d", checked);
}

Test(expr_eval, interval_on_a_point_box_is_tight)
{
    expr_tape *t = compile_ok("sqrt(x^2+y^2+z^2)-0.8");
    ival v = expr_eval_ival(t, ival_point(0.3), ival_point(0.4), ival_point(0.5));
    double p = expr_eval_point(t, 0.3, 0.4, 0.5);
    cr_expect(v.lo <= p && p <= v.hi && v.hi - v.lo < 1e-14);
    expr_tape_free(t);
}

/* ---- gradient against finite differences ---- */

/* Central difference; *noise gets its rounding error bound. */
static double fd(expr_vm *vm, const double p[3], int j, double h, double *noise)
{
    double a[3] = {p[0], p[1], p[2]}, b[3] = {p[0], p[1], p[2]};
    a[j] += h;
    b[j] -= h;
    double fa = expr_vm_point(vm, 0, a[0], a[1], a[2]), fb = expr_vm_point(vm, 0, b[0], b[1], b[2]);
    *noise = 64 * DBL_EPSILON * fmax(fabs(fa), fabs(fb)) / (2 * (a[j] - b[j]));
    return (fa - fb) / (a[j] - b[j]);
}

Test(expr_eval, gradient_matches_finite_differences)
{
    rng_seed(5);
    int checked = 0, tried = 0;
    for (int e = 0; e < 250; e++) {
        char *src = random_source(2 + e % 3, 1);
        expr_tape *t = compile_ok(src);
        expr_vm *vm;
        cr_assert_eq(expr_vm_new(t, 0, &vm), 0);
        for (int k = 0; k < 10; k++) {
            double p[3] = {urand(-2, 2), urand(-2, 2), urand(-2, 2)}, g[3];
            double v = expr_vm_grad(vm, 0, p[0], p[1], p[2], g);
            cr_assert(same_double(v, expr_vm_point(vm, 0, p[0], p[1], p[2])), "%s", src);
            for (int j = 0; j < 3; j++) {
                double h = 1e-5 * fmax(1, fabs(p[j]));
                double n1, n2, d1 = fd(vm, p, j, h, &n1), d2 = fd(vm, p, j, h / 2, &n2);
                double tol = 1e-6 * fmax(1, fabs(d2));
                tried++;
                /* skip kinks and poles (the two estimates disagree) and values
                 * so large that rounding swamps the difference */
                if (!isfinite(d1) || !isfinite(d2) || fabs(d1 - d2) > tol || n2 > tol)
                    continue;
                checked++;
                cr_assert(fabs(g[j] - d2) <= 1e-5 * fmax(1, fabs(d2)),
                          "%s at (%.17g,%.17g,%.17g): d/d%c = %.17g, finite differences %.17g",
                          src, p[0], p[1], p[2], "xyz"[j], g[j], d2);
            }
        }
        expr_vm_free(vm);
        expr_tape_free(t);
        free(src);
    }
    cr_expect_gt(checked, tried / 2, "only %d of %d derivatives checked", checked, tried);
}

Test(expr_eval, gradient_special_points)
{
    expr_vm *vm;
    double g[3];
    expr_tape *t = compile_ok("sqrt(x^2+y^2+z^2) - 1");
    cr_assert_eq(expr_vm_new(t, 0, &vm), 0);
    expr_vm_grad(vm, 0, 0.6, 0, 0.8, g);
    cr_expect(close_to(g[0], 0.6, 1e-15) && close_to(g[1], 0, 0) && close_to(g[2], 0.8, 1e-15));
    expr_vm_grad(vm, 0, 0, 0, 0, g); /* finite, not NaN */
    cr_expect(isfinite(g[0]) && isfinite(g[1]) && isfinite(g[2]));
    expr_vm_free(vm);
    expr_tape_free(t);
    /* r, theta, phi on the z axis and at the origin */
    const char *sph[] = {"r", "theta", "phi", "sin(4*theta)*sin(8*phi) - r"};
    double pts[][3] = {{0, 0, 0}, {0, 0, 1}, {0, 0, -2}, {1e-300, 0, 1}, {-1, 0, 0}};
    for (int i = 0; i < 4; i++) {
        t = compile_ok(sph[i]);
        cr_assert_eq(expr_vm_new(t, 0, &vm), 0);
        for (int k = 0; k < 5; k++) {
            double v = expr_vm_grad(vm, 0, pts[k][0], pts[k][1], pts[k][2], g);
            cr_expect(isfinite(v) && isfinite(g[0]) && isfinite(g[1]) && isfinite(g[2]),
                      "%s at point %d: %g (%g %g %g)", sph[i], k, v, g[0], g[1], g[2]);
        }
        expr_vm_free(vm);
        expr_tape_free(t);
    }
    /* r gradient is the unit vector; theta's is (-y, x)/rho^2; phi's points south */
    t = compile_ok("r + 10*theta + 100*phi");
    cr_assert_eq(expr_vm_new(t, 0, &vm), 0);
    expr_vm_grad(vm, 0, 1, 1, 0, g);
    double s = sqrt(0.5);
    cr_expect(close_to(g[0], s - 5, 1e-14) && close_to(g[1], s + 5, 1e-14) &&
              close_to(g[2], -100 / sqrt(2), 1e-14), "%g %g %g", g[0], g[1], g[2]);
    expr_vm_free(vm);
    expr_tape_free(t);
    /* abs, min, max follow the active branch */
    t = compile_ok("abs(x) + min(y, 2*z) + max(3*x, z)");
    cr_assert_eq(expr_vm_new(t, 0, &vm), 0);
    expr_vm_grad(vm, 0, -1, 1, 1, g); /* -x + y + z */
    cr_expect(g[0] == -1 && g[1] == 1 && g[2] == 1);
    expr_vm_grad(vm, 0, 2, 3, 1, g); /* x + 2z + 3x */
    cr_expect(g[0] == 4 && g[1] == 0 && g[2] == 2);
    expr_vm_free(vm);
    expr_tape_free(t);
}

/* ---- pruning ---- */

static void put_sphere(gen *g, double cx, double cy, double cz, double r)
{
    put(g, "sqrt((x-%.3f)^2+(y-%.3f)^2+(z-%.3f)^2)-%.3f", cx, cy, cz, r);
}

/* A pruned tape is F inside its box: point values and gradients bit for
 * bit equal to the full tape's (where F is defined: a dropped branch may
 * have been NaN there), intervals on sub-boxes still enclose. */
static void check_pruned(expr_vm *vm, int d, const ival box[3], const char *src)
{
    for (int k = 0; k < 24; k++) {
        double p[3], g0[3], g1[3];
        sample(box, k, p);
        double v0 = expr_vm_point(vm, 0, p[0], p[1], p[2]);
        double v1 = expr_vm_point(vm, d, p[0], p[1], p[2]);
        if (isnan(v0)) continue;
        cr_assert(same_double(v0, v1), "%s: depth %d %.17g vs %.17g", src, d, v1, v0);
        double w0 = expr_vm_grad(vm, 0, p[0], p[1], p[2], g0);
        double w1 = expr_vm_grad(vm, d, p[0], p[1], p[2], g1);
        cr_assert(same_double(w0, w1) && same_double(g0[0], g1[0]) &&
                  same_double(g0[1], g1[1]) && same_double(g0[2], g1[2]), "%s", src);
    }
}

static void child_box(const ival box[3], int c, ival out[3])
{
    for (int j = 0; j < 3; j++) {
        double m = 0.5 * (box[j].lo + box[j].hi);
        out[j] = (c >> j) & 1 ? ival_make(m, box[j].hi) : ival_make(box[j].lo, m);
    }
}

/* Evaluate box at depth d, prune, check depth d+1 inside it, recurse into
 * two children.  Returns how many prunes shortened the tape. */
static int prune_walk(expr_vm *vm, int d, const ival box[3], int levels, const char *src)
{
    ival I = expr_vm_ival(vm, d, box[0], box[1], box[2]);
    for (int k = 0; k < 16; k++) {
        double p[3];
        sample(box, k, p);
        double v = defined_point(vm, 0, p);
        cr_assert(encloses(I, v), "%s: depth %d: %.17g not in [%.17g, %.17g]", src, d, v,
                  I.lo, I.hi);
    }
    if (!levels) return 0;
    uint32_t before = expr_vm_length(vm, d), decided = vm->dep[d].decided;
    expr_vm_prune(vm, d);
    uint32_t after = expr_vm_length(vm, d + 1);
    /* a decided min/max is dropped (renamed to its winner), at least */
    if (decided) cr_assert_lt(after, before, "%s: %u decided", src, decided);
    else cr_assert(after == before && vm->dep[d + 1].code == vm->dep[d].code, "%s", src);
    check_pruned(vm, d + 1, box, src);
    int shortened = after < before;
    for (int c = 0; c < 2; c++) {
        ival sub[3];
        child_box(box, irand(8), sub);
        shortened += prune_walk(vm, d + 1, sub, levels - 1, src);
    }
    return shortened;
}

static char *spheres_source(int n)
{
    gen g = {malloc(1 << 16), 0, 1 << 16, 0};
    put(&g, "min(");
    for (int i = 0; i < n; i++) {
        if (i) put(&g, ",\n    ");
        put_sphere(&g, urand(-1, 1), urand(-1, 1), urand(-1, 1), urand(0.05, 0.25));
    }
    put(&g, ")");
    return g.buf;
}

Test(expr_prune, min_of_spheres_is_bit_exact)
{
    rng_seed(6);
    char *src = spheres_source(64);
    expr_tape *t = compile_ok(src);
    expr_vm *vm;
    cr_assert_eq(expr_vm_new(t, 6, &vm), 0);
    int shortened = 0;
    for (int b = 0; b < 40; b++) {
        ival box[3];
        for (int j = 0; j < 3; j++) {
            double c = urand(-1.1, 1.1), w = pow(10, urand(-2, -0.5));
            box[j] = ival_make(c - w, c + w);
        }
        shortened += prune_walk(vm, 0, box, 3, src);
    }
    cr_expect_gt(shortened, 40, "pruning hardly ever shortened the tape (%d)", shortened);
    expr_vm_free(vm);
    expr_tape_free(t);
    free(src);
}

/* Well separated spheres: around one centre every min is decided, and what
 * is left is exactly that sphere's own tape. */
Test(expr_prune, decided_min_leaves_the_winner_only)
{
    gen g = {malloc(1 << 16), 0, 1 << 16, 0};
    put(&g, "min(");
    for (int i = 0; i < 64; i++) {
        if (i) put(&g, ", ");
        put_sphere(&g, i % 4, (i / 4) % 4, i / 16, 0.3);
    }
    put(&g, ")");
    expr_tape *t = compile_ok(g.buf);
    expr_vm *vm;
    cr_assert_eq(expr_vm_new(t, 2, &vm), 0);
    rng_seed(7);
    for (int k = 0; k < 64; k += 7) {
        double c[3] = {k % 4, (k / 4) % 4, k / 16};
        ival box[3];
        for (int j = 0; j < 3; j++) box[j] = ival_make(c[j] - 0.1, c[j] + 0.1);
        expr_vm_ival(vm, 0, box[0], box[1], box[2]);
        expr_vm_prune(vm, 0);
        gen one = {malloc(256), 0, 256, 0};
        put_sphere(&one, c[0], c[1], c[2], 0.3);
        expr_tape *alone = compile_ok(one.buf);
        cr_expect_eq(expr_vm_length(vm, 1), expr_tape_length(alone), "sphere %d", k);
        cr_expect_lt(expr_vm_length(vm, 1), expr_vm_length(vm, 0));
        for (int s = 0; s < 20; s++) {
            double p[3];
            sample(box, s, p);
            cr_expect(same_double(expr_vm_point(vm, 1, p[0], p[1], p[2]),
                                  expr_eval_point(alone, p[0], p[1], p[2])));
        }
        check_pruned(vm, 1, box, g.buf);
        expr_tape_free(alone);
        free(one.buf);
    }
    expr_vm_free(vm);
    expr_tape_free(t);
    free(g.buf);
}

static void gen_csg(gen *g, int depth)
{
    if (depth == 0 || irand(4) == 0) {
        if (irand(3))
            put_sphere(g, urand(-1, 1), urand(-1, 1), urand(-1, 1), urand(0.1, 0.6));
        else
            put(g, "(x*%.2f + y*%.2f + z*%.2f - %.2f)", urand(-1, 1), urand(-1, 1),
                urand(-1, 1), urand(-1, 1));
        return;
    }
    int k = irand(3), n = 2 + irand(2);
    put(g, k == 0 ? "min(" : "max(");
    for (int i = 0; i < n; i++) {
        if (i) put(g, ", ");
        if (k == 2 && i) put(g, "-(");
        gen_csg(g, depth - 1);
        if (k == 2 && i) put(g, ")");
    }
    put(g, ")");
}

Test(expr_prune, nested_min_max_is_bit_exact_and_sound)
{
    rng_seed(8);
    int shortened = 0;
    for (int e = 0; e < 60; e++) {
        gen g = {malloc(1 << 16), 0, 1 << 16, 0};
        gen_csg(&g, 4);
        if (e % 3 == 0) put(&g, " + 0.05*sin(9*x)*blend(y, 0.5)");
        expr_tape *t = compile_ok(g.buf);
        expr_vm *vm;
        cr_assert_eq(expr_vm_new(t, 5, &vm), 0);
        for (int b = 0; b < 6; b++) {
            ival box[3];
            random_box(box, 0.5);
            shortened += prune_walk(vm, 0, box, 3, g.buf);
        }
        expr_vm_free(vm);
        expr_tape_free(t);
        free(g.buf);
    }
    cr_expect_gt(shortened, 60, "pruning hardly ever shortened the tape (%d)", shortened);
}

Test(expr_prune, nothing_decided_and_depth_clamping)
{
    expr_tape *t = compile_ok("min(sqrt(x^2+y^2+z^2)-0.5, x+0.2)");
    expr_vm *vm;
    cr_assert_eq(expr_vm_new(t, 2, &vm), 0);
    uint32_t n = expr_tape_length(t);
    /* the box straddles both: nothing decided, same tape */
    expr_vm_ival(vm, 0, ival_make(-0.5, -0.3), ival_make(-0.1, 0.1), ival_make(-0.1, 0.1));
    expr_vm_prune(vm, 0);
    cr_expect_eq(expr_vm_length(vm, 1), n);
    /* far left: x+0.2 wins (one instruction); deeper depths clamp to 2 */
    ival X = ival_make(-0.8, -0.7), Y = ival_make(0, 0.05), Z = ival_make(0, 0.05);
    expr_vm_ival(vm, 1, X, Y, Z);
    expr_vm_prune(vm, 1);
    cr_expect_eq(expr_vm_length(vm, 2), 1);
    expr_vm_prune(vm, 2); /* no deeper tape: a no-op */
    cr_expect_eq(expr_vm_length(vm, 9), 1);
    cr_expect(same_double(expr_vm_point(vm, 9, -0.75, 0.01, 0.02), -0.75 + 0.2));
    ival I = expr_vm_ival(vm, 30, X, Y, Z);
    cr_expect(I.lo <= -0.6 && I.hi >= -0.5 && I.hi < 0);
    cr_expect_eq(expr_vm_length(vm, -4), n);
    /* a tape that is a single register (x): depth tapes stay empty */
    expr_tape *tx = compile_ok("min(x, 5)");
    expr_vm *vx;
    cr_assert_eq(expr_vm_new(tx, 3, &vx), 0);
    expr_vm_ival(vx, 0, ival_make(0, 1), ival_make(0, 1), ival_make(0, 1));
    expr_vm_prune(vx, 0);
    cr_expect_eq(expr_vm_length(vx, 1), 0);
    cr_expect_eq(expr_vm_point(vx, 1, 0.25, 0, 0), 0.25);
    ival J = expr_vm_ival(vx, 1, ival_make(0, 0.5), ival_make(0, 1), ival_make(0, 1));
    cr_expect(J.lo == 0 && J.hi == 0.5);
    expr_vm_free(vx);
    expr_tape_free(tx);
    expr_vm_free(vm);
    expr_tape_free(t);
}

/* ---- batched evaluators: every lane is the one-box evaluation ---- */

static int same_ival(ival a, ival b) { return same_double(a.lo, b.lo) && same_double(a.hi, b.hi); }

/* Random boxes with the awkward cases mixed in: huge and infinite bounds
 * (overflow, 0 * inf products), zero-width boxes, exact zeros (divisors
 * touching 0). */
static void batch_box(ival box[3])
{
    random_box(box, 1.0);
    for (int j = 0; j < 3; j++) {
        switch (irand(24)) {
        case 0: box[j] = ival_make(-INFINITY, box[j].hi); break;
        case 1: box[j] = ival_make(box[j].lo, INFINITY); break;
        case 2: box[j] = ival_make(1e300, 1e308); break;
        case 3: box[j] = ival_make(-DBL_MAX, -1e200); break;
        case 4: box[j] = ival_point(box[j].lo); break;
        case 5: box[j] = ival_point(0); break;
        case 6: box[j] = ival_make(-0.0, 0.0); break;
        default: break;
        }
    }
}

static int same_tape(const expr_vm *a, const expr_vm *b, int d)
{
    const expr_vm_depth *x = &a->dep[d], *y = &b->dep[d];
    return x->len == y->len && x->result == y->result &&
           !memcmp(x->code, y->code, x->len * sizeof *x->code);
}

static void check_batch(const char *src, int nbatches)
{
    expr_tape *t = compile_ok(src);
    expr_vm *v8, *v1;
    cr_assert_eq(expr_vm_new(t, 2, &v8), 0);
    cr_assert_eq(expr_vm_new(t, 2, &v1), 0);
    for (int b = 0; b < nbatches; b++) {
        ival box[EXPR_LANES][3];
        ival8 X, Y, Z, I8;
        for (int l = 0; l < EXPR_LANES; l++) {
            if (l && irand(4) == 0) memcpy(box[l], box[irand(l)], sizeof box[l]);
            else batch_box(box[l]);
            X.lo[l] = box[l][0].lo, X.hi[l] = box[l][0].hi;
            Y.lo[l] = box[l][1].lo, Y.hi[l] = box[l][1].hi;
            Z.lo[l] = box[l][2].lo, Z.hi[l] = box[l][2].hi;
        }
        expr_vm_ival8(v8, 0, &X, &Y, &Z, &I8);
        for (int l = 0; l < EXPR_LANES; l++) {
            ival I = expr_vm_ival(v1, 0, box[l][0], box[l][1], box[l][2]);
            cr_assert(same_ival(I, ival_make(I8.lo[l], I8.hi[l])),
                      "%s\n lane %d: [%.17g, %.17g] vs one box [%.17g, %.17g]", src, l,
                      I8.lo[l], I8.hi[l], I.lo, I.hi);
            /* pruning for the lane builds the one-box tape; lanes in any order */
            expr_vm_prune(v1, 0);
            expr_vm_prune8(v8, 0, l);
            cr_assert(same_tape(v8, v1, 1), "%s: lane %d prunes differently", src, l);
        }
        /* gradients at a point of each box */
        _Alignas(64) double px[EXPR_LANES], py[EXPR_LANES], pz[EXPR_LANES];
        for (int l = 0; l < EXPR_LANES; l++) {
            double p[3];
            sample(box[l], 8 + irand(2) * 8, p);
            if (irand(8) == 0) p[irand(3)] = 0;
            px[l] = p[0], py[l] = p[1], pz[l] = p[2];
        }
        int d = irand(2);
        expr_grad8 g8;
        expr_vm_grad8(v8, d, px, py, pz, &g8);
        for (int l = 0; l < EXPR_LANES; l++) {
            double g[3], v = expr_vm_grad(v8, d, px[l], py[l], pz[l], g);
            cr_assert(same_double(v, g8.v[l]) && same_double(g[0], g8.d[0][l]) &&
                          same_double(g[1], g8.d[1][l]) && same_double(g[2], g8.d[2][l]),
                      "%s: gradient lane %d at (%.17g, %.17g, %.17g)", src, l, px[l], py[l],
                      pz[l]);
        }
        /* a partial batch: the same lanes */
        int n = 1 + irand(EXPR_LANES);
        expr_grad8 gn;
        expr_vm_grad8n(v8, d, n, px, py, pz, &gn);
        for (int l = 0; l < n; l++)
            cr_assert(same_double(gn.v[l], g8.v[l]) && same_double(gn.d[0][l], g8.d[0][l]) &&
                          same_double(gn.d[1][l], g8.d[1][l]) &&
                          same_double(gn.d[2][l], g8.d[2][l]),
                      "%s: partial batch of %d, lane %d", src, n, l);
    }
    expr_vm_free(v8);
    expr_vm_free(v1);
    expr_tape_free(t);
}

Test(expr_batch, lanes_are_the_one_box_evaluation)
{
    rng_seed(11);
    for (int e = 0; e < 300; e++) {
        char *src = random_source(2 + e % 4, e % 2);
        check_batch(src, 6);
        free(src);
    }
    for (int e = 0; e < 40; e++) {
        gen g = {malloc(1 << 16), 0, 1 << 16, 0};
        gen_csg(&g, 4);
        check_batch(g.buf, 6);
        free(g.buf);
    }
    const char *fixed[] = {"sqrt(x^2 + y^2 + z^2) - 0.8", "x*y - z", "x/y + z/(x+1)",
                           "min(x, y, z) - max(x*y, -z)", "abs(x) - sqrt(y) + -z",
                           "-log(exp(-44*x) + exp(-44*y)) / 44"};
    for (size_t i = 0; i < sizeof fixed / sizeof *fixed; i++) check_batch(fixed[i], 50);
}

/* ---- the paper's scenes ---- */

static double scene(double x, double y, double z, int a, int b)
{
    double r = sqrt(x * x + y * y + z * z);
    return sin(a * atan2(y, x)) * sin(b * acos(z / r)) - r;
}

Test(expr_scenes, stolte_kaufman_scenes_2_and_3)
{
    const char *src[] = {"sin(4*theta)*sin(8*phi) - r", "sin(3*theta)*sin(4*phi) - r"};
    int ab[][2] = {{4, 8}, {3, 4}};
    rng_seed(9);
    for (int s = 0; s < 2; s++) {
        expr_tape *t = compile_ok(src[s]);
        /* theta, mul, sin, phi, mul, sin, mul, r, sub */
        cr_expect_eq(expr_tape_length(t), 9u);
        expr_vm *vm;
        cr_assert_eq(expr_vm_new(t, 8, &vm), 0);
        for (int k = 0; k < 200; k++) {
            double x = urand(-1, 1), y = urand(-1, 1), z = urand(-1, 1);
            cr_expect(close_to(expr_vm_point(vm, 0, x, y, z), scene(x, y, z, ab[s][0], ab[s][1]),
                               1e-12));
        }
        for (int b = 0; b < 200; b++) {
            ival box[3];
            random_box(box, 0.5);
            ival I = expr_vm_ival(vm, 0, box[0], box[1], box[2]);
            for (int k = 0; k < 24; k++) {
                double p[3];
                sample(box, k, p);
                double v = defined_point(vm, 0, p);
                cr_assert(encloses(I, v), "%s: %.17g not in [%.17g, %.17g]", src[s], v, I.lo,
                          I.hi);
            }
        }
        expr_vm_free(vm);
        expr_tape_free(t);
    }
}
