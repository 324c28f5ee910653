/* afterexit — what a command's exit would make its user wait for, done
 * after the exit instead.
 *
 * A process's exit tears its address space down before its parent (the
 * shell) hears of it: the page tables of every mapping (2 GiB of shared
 * segment in the master), the heap's pages (the bricks, the plan).  And
 * a rename over an existing file frees that file's blocks and pages
 * (tens of MB: 0.02 s and more) before it returns.  afterexit_leave()
 * hands both to a helper: a child that shares this process's memory
 * (clone with CLONE_VM, as posix_spawn's child does), so that our exit
 * only drops our reference to the address space, and that holds the
 * replaced file open, so that the rename only unlinks it.  The helper
 * waits until our end of a pipe closes (our exit), then closes the file
 * and exits: the last user of the memory, it tears it down, after the
 * user has seen the command end.  The init process (or a subreaper)
 * reaps it, as it does the workers of an abandoned engine.
 */
#ifndef VOXD_AFTEREXIT_H
#define VOXD_AFTEREXIT_H

/* The regular file at path, opened for afterexit_leave (call it before
 * the rename that replaces it): a descriptor, or -1 when there is none
 * (or it has other names, or is not a regular file). */
int afterexit_hold(const char *path);

/* Starts the helper, which holds fd (a descriptor from afterexit_hold,
 * or -1) and this process's memory until this process has exited; fd is
 * closed here either way.  Call it last, when the process exits next
 * (what it does after, the helper does not wait for).  Where no helper
 * can be made, the exit does it all, as without this call. */
void afterexit_leave(int fd);

#endif
