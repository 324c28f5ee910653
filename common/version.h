#ifndef VOX_VERSION_H
#define VOX_VERSION_H
/* The version and the git commit vox and voxd were built from: the Makefile
 * passes both with -D to the two objects that print them; "unknown" when
 * built another way. */
#ifndef VOX_VERSION
#define VOX_VERSION "unknown"
#endif
#ifndef VOX_COMMIT
#define VOX_COMMIT "unknown"
#endif
#endif
