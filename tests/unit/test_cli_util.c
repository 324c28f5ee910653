/* The command line's file reader (cli_read_file): a file larger than one
 * part (4 MiB) read by several threads at their offsets, each byte where
 * it was, the size past the limit refused, a directory and a missing file
 * refused with their own errors, a file shorter than its size refused. */
#include <criterion/criterion.h>
#include <errno.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "cli.h"

/* A file of n bytes, byte i a function of i, at a fresh path (unlinked by
 * the caller). */
static void make_file(char *path, size_t n)
{
    int fd = mkstemp(path);
    cr_assert_geq(fd, 0);
    uint8_t *b = malloc(n ? n : 1);
    for (size_t i = 0; i < n; i++) b[i] = (uint8_t)(i * 2654435761u >> 13);
    cr_assert_eq(write(fd, b, n), (ssize_t)n);
    free(b);
    close(fd);
}

Test(cli_util, a_file_of_several_parts_reads_whole_and_in_order)
{
    const size_t sizes[] = {0, 1, 4095, ((size_t)4 << 20) + 3, ((size_t)13 << 20) + 77};
    for (size_t k = 0; k < sizeof sizes / sizeof *sizes; k++) {
        char path[] = "/tmp/test_cli_util_XXXXXX";
        make_file(path, sizes[k]);
        char *data;
        size_t len;
        cr_assert_eq(cli_read_file(path, SIZE_MAX, &data, &len), 0, "%zu bytes", sizes[k]);
        cr_assert_eq(len, sizes[k]);
        cr_assert_eq(data[len], '\0', "not terminated");
        for (size_t i = 0; i < len; i++)
            if ((uint8_t)data[i] != (uint8_t)(i * 2654435761u >> 13))
                cr_assert_fail("%zu bytes: byte %zu differs", sizes[k], i);
        free(data);
        unlink(path);
    }
}

Test(cli_util, files_it_cannot_read_are_refused_typed)
{
    char path[] = "/tmp/test_cli_util_XXXXXX";
    make_file(path, 100);
    char *data = NULL;
    size_t len = 0;
    cr_assert_eq(cli_read_file(path, 99, &data, &len), -EFBIG);
    cr_assert_eq(cli_read_file(path, 100, &data, &len), 0);
    free(data);
    unlink(path);
    cr_assert_eq(cli_read_file(path, 100, &data, &len), -ENOENT);
    cr_assert_eq(cli_read_file("/tmp", SIZE_MAX, &data, &len), -EISDIR);
}

/* A file that ends before its size (as one cut short while it is read):
 * sysfs gives every attribute a size of a page and a few bytes of text. */
Test(cli_util, a_file_shorter_than_its_size_is_an_input_error)
{
    const char *path = "/sys/devices/system/cpu/online";
    struct stat st;
    cr_assert_eq(stat(path, &st), 0, "%s: %s (the test needs sysfs)", path, strerror(errno));
    cr_assert_gt(st.st_size, 16, "%s: size %lld, no longer than its text", path,
                 (long long)st.st_size);
    char *data = NULL;
    size_t len = 0;
    cr_assert_eq(cli_read_file(path, SIZE_MAX, &data, &len), -EIO);
    cr_assert_null(data);
}
