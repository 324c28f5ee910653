/* Replays a fuzz harness over every file of a corpus directory, so that
 * `make test` runs each harness on its seeds under the sanitizers without
 * libFuzzer.  Every input that returns prints "PASS: <file>" (line by line,
 * so the last one before a crash names the input before the culprit), and a
 * run that reaches its end prints "REPLAYED: N inputs, M failed".  A
 * sanitizer report or an abort ends the run before that line; the runner
 * wants the line, N equal to the corpus' file count, and exit status 0. */
#include <dirent.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static int replay(const char *path)
{
    FILE *f = fopen(path, "rb");
    if (!f) {
        printf("FAIL: %s: cannot open\n", path);
        return 1;
    }
    uint8_t *buf = malloc(1 << 20);
    size_t n = buf ? fread(buf, 1, 1 << 20, f) : 0;
    fclose(f);
    if (!buf) return 1;
    LLVMFuzzerTestOneInput(buf, n);
    free(buf);
    printf("PASS: %s\n", path);
    return 0;
}

int main(int argc, char **argv)
{
    if (argc != 2) {
        fprintf(stderr, "usage: %s CORPUS_DIR\n", argv[0]);
        return 2;
    }
    DIR *d = opendir(argv[1]);
    if (!d) {
        printf("FAIL: %s: no corpus directory\n", argv[1]);
        return 1;
    }
    setvbuf(stdout, NULL, _IOLBF, 0);
    int bad = 0, n = 0, nbad = 0;
    struct dirent *e;
    char path[4096];
    while ((e = readdir(d))) {
        if (e->d_name[0] == '.') continue;
        snprintf(path, sizeof path, "%s/%s", argv[1], e->d_name);
        int r = replay(path);
        bad |= r;
        nbad += r;
        n++;
    }
    closedir(d);
    printf("REPLAYED: %d inputs, %d failed\n", n, nbad);
    return bad;
}
