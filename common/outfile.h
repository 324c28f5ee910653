/* outfile — a result file that appears whole or not at all.
 *
 * outfile_create() makes a new file beside PATH under a temporary name
 * (PATH.tmp.XXXXXX, created exclusively, mode 0666 less the umask like any
 * file the user writes); the caller writes it, then renames it onto PATH
 * when it is complete and unlinks it otherwise.  vox voxelize and libvox
 * both write their VOD files this way.
 */
#ifndef VOXD_OUTFILE_H
#define VOXD_OUTFILE_H

#include <stddef.h>

/* The open fd (O_WRONLY, O_CLOEXEC) with its name in tmp, or a negative
 * errno (-ENAMETOOLONG when the name does not fit in cap). */
int outfile_create(const char *path, char *tmp, size_t cap);

#endif
