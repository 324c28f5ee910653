/* The expression language: parsing (precedence, functions against libm,
 * spherical coordinates, named values, comments), errors with exact positions,
 * limits, folding and sharing.  The tape and the evaluators: test_expr_eval.c. */
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

#include "expr_fixture.h"

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
    cr_expect_eq(e.code, rc, "\"%s\": code %d, returned %d", b->src, e.code, rc);
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
