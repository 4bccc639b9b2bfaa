// What fresh memory costs on this machine: maps anonymous memory in 512 MB pieces and times the
// first write to each of its pages, twice (everything unmapped, then a pause, between the two
// passes). docs/performance.md ("The first run's step, explained") has what it showed.
//   cc -O2 -o /tmp/first_touch scripts/first_touch.c && /tmp/first_touch [pieces=16] [pause_s=5]
#include <stdio.h>
#include <stdlib.h>
#include <sys/mman.h>
#include <time.h>
#include <unistd.h>

static double now_s(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

int main(int argc, char** argv) {
  const int pieces = argc > 1 ? atoi(argv[1]) : 16;
  const int pause_s = argc > 2 ? atoi(argv[2]) : 5;
  if (pieces < 1 || pieces > 256 || pause_s < 0) {
    fprintf(stderr, "usage: %s [pieces 1..256] [pause_s >= 0]\n", argv[0]);
    return 2;
  }
  const size_t piece = (size_t)512 << 20;
  char** p = calloc((size_t)pieces, sizeof *p);
  if (!p) return 1;
  for (int pass = 0; pass < 2; ++pass) {
    printf("pass %d, GB/s per 512 MB piece:", pass);
    for (int i = 0; i < pieces; ++i) {
      p[i] = mmap(0, piece, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
      if (p[i] == MAP_FAILED) {
        perror("mmap");
        return 1;
      }
      const double t = now_s();
      for (size_t o = 0; o < piece; o += 4096) p[i][o] = 1;
      printf(" %.2f", (double)piece / (now_s() - t) / 1e9);
      fflush(stdout);
    }
    printf("\n");
    for (int i = 0; i < pieces; ++i) munmap(p[i], piece);
    sleep((unsigned)pause_s);
  }
  free(p);
  return 0;
}
