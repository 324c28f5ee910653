/* cli — the subcommands of `vox` and the small parsers they share. */
#ifndef VOXD_CLI_H
#define VOXD_CLI_H

#include <stddef.h>
#include <stdint.h>

int cli_voxelize(int argc, char **argv);
int cli_info(int argc, char **argv);
int cli_render(int argc, char **argv);

/* Parse "a,b" (a cube [a,b]^3) or "x0,x1,y0,y1,z0,z1" into lo/hi. */
int cli_parse_domain(const char *s, double lo[3], double hi[3]);
/* Parse a CPU list "0,2,4-7" into cpus (up to cap); returns the count or -1. */
int cli_parse_cpus(const char *s, int *cpus, int cap);
/* Parse a whole decimal number in [min, max]; -1 on error. */
int cli_parse_uint(const char *s, uint32_t min, uint32_t max, uint32_t *out);
/* Read a whole file (at most max bytes) into a NUL-terminated buffer. */
int cli_read_file(const char *path, size_t max, char **out, size_t *len);
/* Print "vox: " + message to stderr. */
void cli_error(const char *fmt, ...) __attribute__((format(printf, 1, 2)));

#endif
