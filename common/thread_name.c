/* Thread names: see thread_name.h. */
#include "thread_name.h"

#include <errno.h>
#include <stdio.h>
#include <sys/prctl.h>

/* Written once by the main thread before it makes any other (the makers'
 * pthread_create and fork order the write before their reads). */
static int names_on;

void thread_name_enable(void)
{
    names_on = 1;
}

void thread_name(const char *what)
{
    if (!names_on) return;
    char name[16];
    snprintf(name, sizeof name, "%s %s", program_invocation_short_name, what);
    prctl(PR_SET_NAME, name, 0, 0, 0); /* a name only: nothing to do if it fails */
}
