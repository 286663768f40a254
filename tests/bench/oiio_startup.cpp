// A program linked to OpenImageIO and nothing else of the project, that does nothing: what
// starting any OpenImageIO tool costs (the dynamic loader binding OpenImageIO and the libraries it
// needs). compose-bench-pipeline times it to compare whole processes fairly.
#include <cstdio>

#include <OpenImageIO/imageio.h>

int main(int argc, char** /*argv*/) {
  // Referenced, so that the link keeps OpenImageIO; printed only if asked for.
  if (argc > 1) std::printf("%d\n", OIIO::openimageio_version());
  return 0;
}
