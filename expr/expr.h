/* expr — the expression language for F(x,y,z) and its compiled tape.
 *
 * Source language (see docs/expressions.md):
 *   numbers, x y z, r theta phi (spherical: theta = atan2(y,x), phi = angle from +z),
 *   + - * / ^, unary minus, parentheses, pi,
 *   sin cos tan asin acos atan atan2 exp log sqrt abs min max pow blend(d,R),
 *   named values "a = <expr>;" before the final expression; '#' starts a comment.
 *   min and max take two or more arguments.  Grammar and messages: expr_parse.c.
 *
 * Point semantics (what the point and gradient evaluators compute, and what
 * the interval evaluator encloses): IEEE doubles and libm, except that
 * F is undefined (NaN) wherever an operand is: min, max, blend and pow
 * propagate NaN (C's fmin, pow(1, NaN) would not), and pow(a, b) with a < 0
 * needs an integer b.  phi at the origin is 0, theta there is atan2(0, 0) = 0.
 * x^n for a constant integer n is an integer power (x^2: x*x); blend's R must
 * be a positive finite constant.  At an exact pole (1/0, log(0)) the sign of
 * the infinity comes from the sign of a zero, which intervals do not carry:
 * such points, like NaN ones, are outside F's domain and never on F = 0.
 *
 * expr_compile() parses once and emits a flat register tape (constant folding,
 * common subexpressions shared).  The tape is one position-independent block of
 * bytes (no pointers inside), so it can be copied into shared memory with memcpy
 * and used from another process.
 *
 * Evaluation goes through an expr_vm: per-thread scratch registers plus one
 * tape per subdivision depth.  Interval evaluation at depth d records, for every
 * min/max, which side won on that box; expr_vm_prune(d) then builds the tape for
 * depth d+1 with the branches that cannot matter inside that box removed, so
 * deep octants run a much shorter tape.  A pruned tape equals F bit for bit
 * in the box it was pruned for (wherever F is defined: a dropped branch may
 * have been NaN there), so point and gradient evaluation inside that box may
 * use it too.  Pruning is deterministic: the tape of depth d+1 depends only
 * on tape d and the box, never on what the vm evaluated before.
 */
#ifndef VOXD_EXPR_H
#define VOXD_EXPR_H

#include <stddef.h>
#include <stdint.h>

#include "err.h"
#include "ival.h"

typedef struct expr_tape expr_tape;
typedef struct expr_vm expr_vm;

/* Limits on the untrusted source; each violation is its own error message
 * and -E2BIG.  A field left 0 takes its default.  max_depth bounds the
 * parser's and the compiler's recursion (about 0.5 KB of stack per level),
 * counting real nesting only: parentheses, function calls, unary minus and
 * '^'.  A flat chain a+b-c+... or a*b/c*... of any length is one level,
 * and so is min(a, b, c, ...) whatever its argument count; max_source_bytes
 * and max_nodes bound their size. */
typedef struct {
    uint32_t max_source_bytes; /* default 65536 */
    uint32_t max_depth;        /* nesting depth, default 256, at most 1024 */
    uint32_t max_nodes;        /* syntax tree nodes, default 100000 */
} expr_limits;

#define EXPR_DEFAULT_MAX_SOURCE 65536u
#define EXPR_DEFAULT_MAX_DEPTH 256u
#define EXPR_DEFAULT_MAX_NODES 100000u
#define EXPR_MAX_DEPTH_CAP 1024u /* larger max_depth values are lowered to it */

/* The project's error (common/err.h: code the errno returned, msg e.g.
 * "unknown function 'sinn'") and where it is. */
typedef struct {
    ERR_INFO_EMBED(info);
    int line, col;  /* 1-based position of the problem in the source (0 if none) */
} expr_error;

void expr_limits_default(expr_limits *lim);

/* Where an error is, as a compiler shows it: two lines, the source line
 * of line:col and a caret under col, each indented by two spaces and
 * ended by '\n'.  A line longer than EXPR_EXCERPT_WIDTH bytes is cut to a
 * window of that many around col, with "..." where it was cut; tabs show
 * as a space and other control or non-ASCII bytes as '?', one column per
 * byte, so the caret is under the right character.  buf must hold
 * EXPR_EXCERPT_MAX bytes.  0, or -EINVAL (buf "") when src has no such
 * line or col is not positive. */
#define EXPR_EXCERPT_WIDTH 80
#define EXPR_EXCERPT_MAX (2 * (EXPR_EXCERPT_WIDTH + 10) + 1)
int expr_excerpt(const char *src, size_t len, int line, int col, char *buf, size_t n);

/* Compile src (NUL-terminated, len bytes).  lim may be NULL for the defaults.
 * Returns 0 and *out, or -EINVAL (syntax/semantic error) or -E2BIG (a limit)
 * with *err filled in, or -ENOMEM. */
int expr_compile(const char *src, size_t len, const expr_limits *lim,
                 expr_tape **out, expr_error *err);
void expr_tape_free(expr_tape *t);

/* The tape as bytes: copy expr_tape_bytes(t) bytes from t to move it (to
 * any 8-byte aligned address, e.g. into shared memory); the copy is a tape. */
size_t expr_tape_bytes(const expr_tape *t);
/* Check that size bytes at buf hold a well-formed tape (magic, sizes, every
 * register index in range and written before it is read): 0 or -EINVAL.
 * expr_vm_new() runs it too. */
int expr_tape_validate(const void *buf, size_t size);
/* Number of instructions (for tests and the bench's statistics). */
uint32_t expr_tape_length(const expr_tape *t);

/* A vm for tape t (which must outlive it); max_depth is the deepest
 * subdivision depth that will be evaluated (<= 32). */
int expr_vm_new(const expr_tape *t, int max_depth, expr_vm **out);
void expr_vm_free(expr_vm *vm);

/* Evaluate with the tape of depth d (depth 0 is the full tape). */
ival expr_vm_ival(expr_vm *vm, int d, ival x, ival y, ival z);
double expr_vm_point(expr_vm *vm, int d, double x, double y, double z);
/* Value and gradient (forward-mode derivatives) at a point. */
double expr_vm_grad(expr_vm *vm, int d, double x, double y, double z,
                    double grad[3]);
/* Eight boxes (or points) at once: lane l of every argument is one box.
 * The batched evaluators run the tape once for all eight lanes, with
 * registers laid out as arrays of eight (the compiler vectorizes the
 * arithmetic), and compute every lane exactly as the one-box evaluators do
 * with the same arguments: same operations in the same order, so the
 * results, the min/max choices and the pruned tapes are bit for bit those
 * of expr_vm_ival / expr_vm_grad.  Unused lanes may hold anything finite
 * (copies of a used lane are cheapest). */
#define EXPR_LANES 8
typedef struct {
    _Alignas(64) double lo[EXPR_LANES];
    _Alignas(64) double hi[EXPR_LANES];
} ival8;

typedef struct {
    _Alignas(64) double v[EXPR_LANES];     /* F */
    _Alignas(64) double d[3][EXPR_LANES];  /* dF/dx, dF/dy, dF/dz */
} expr_grad8;

/* Interval of F on the eight boxes (x, y, z) lane by lane, with the tape of
 * depth d; records each lane's min/max choices for expr_vm_prune8(). */
void expr_vm_ival8(expr_vm *vm, int d, const ival8 *x, const ival8 *y,
                   const ival8 *z, ival8 *out);
/* The same without copies: fill the three argument registers (x, y, z)
 * that expr_vm_ival8_args returns, then expr_vm_ival8_in evaluates them in
 * place and returns the result register (valid until the vm's next
 * batched interval evaluation; the arguments must be filled again before
 * it, the evaluation may not keep them). */
ival8 *expr_vm_ival8_args(expr_vm *vm);
const ival8 *expr_vm_ival8_in(expr_vm *vm, int d);
/* Eight points: lane l of x, y and z is point l. */
typedef struct {
    _Alignas(64) double x[EXPR_LANES];
    _Alignas(64) double y[EXPR_LANES];
    _Alignas(64) double z[EXPR_LANES];
} expr_pts8;
/* Value and gradient at the eight points p, with the tape of depth d. */
void expr_vm_grad8(expr_vm *vm, int d, const expr_pts8 *p, expr_grad8 *out);
/* The same for lanes 0 .. n-1 only (1 <= n <= 8; p is read and out
 * written up to lane n rounded up to even): a partial batch costs about
 * n/8 of a full one.  Lane for lane the same results. */
void expr_vm_grad8n(expr_vm *vm, int d, int n, const expr_pts8 *p, expr_grad8 *out);
/* expr_vm_prune for the box of lane `lane` of the last expr_vm_ival8 at
 * depth d: tape d+1 becomes exactly what expr_vm_ival on that box followed
 * by expr_vm_prune(d) would build.  The lane choices of depth d stay valid
 * until the next evaluation at depth d, so the kept boxes of one batch can
 * be pruned for one after the other (each one's subtree evaluated in
 * between, with deeper tapes). */
void expr_vm_prune8(expr_vm *vm, int d, int lane);

/* Whether expr_vm_prune8(vm, d, lane) would write a new tape d+1 (some
 * min/max decided in that lane) rather than make tape d+1 share tape d.
 * A written tape overwrites tape d+1's buffer, which tapes deeper than d+1
 * may share. */
int expr_vm_prune8_writes(const expr_vm *vm, int d, int lane);
/* Whether tapes d1 and d2 are the same code (shared, not just equal). */
int expr_vm_same_tape(const expr_vm *vm, int d1, int d2);

/* What expr_vm_ival_grad finds on a box: f and grad[j] enclose what
 * expr_vm_grad gives at every point of the box where that is not NaN. */
typedef struct {
    ival f;       /* F */
    ival grad[3]; /* dF/dx, dF/dy, dF/dz */
    int total;    /* 1: moreover F and its gradient are defined (not NaN)
                     and finite at every point of the box */
} expr_igrad;
/* Intervals of F and of its gradient on the box (x, y, z), with the full
 * tape, into *out.  0, or -ENOTSUP when the tape has an op this evaluator
 * does not know (tan, asin, acos, atan, log, atan2, pow, blend, theta,
 * phi, x^n with n < 1): the caller then decides nothing from it. */
int expr_vm_ival_grad(expr_vm *vm, ival x, ival y, ival z, expr_igrad *out);

/* Build the tape of depth d+1 from the choices of the last expr_vm_ival at
 * depth d.  Call it right after that evaluation.  Cheap when nothing prunes
 * (tape d+1 then shares tape d).  Tapes deeper than d+1 are stale until
 * pruned again.  Depths beyond max_depth use tape max_depth (valid in every
 * box inside the one it was pruned for), and prune(max_depth) does nothing;
 * a negative d means 0. */
void expr_vm_prune(expr_vm *vm, int d);
/* Instructions in the tape of depth d (for statistics). */
uint32_t expr_vm_length(const expr_vm *vm, int d);

/* Convenience wrappers with the full tape (tests, oracles, tools). */
double expr_eval_point(const expr_tape *t, double x, double y, double z);
ival expr_eval_ival(const expr_tape *t, ival x, ival y, ival z);

#endif
