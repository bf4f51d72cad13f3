/* Decodes a JPEG with libjpeg(-turbo) to a binary PPM, as OpenCV's imread does (RGB,
 * default settings), to check the product decoder against libjpeg-turbo pixel for pixel:
 *   gcc -O2 libjpeg_to_ppm.c -o /tmp/libjpeg_to_ppm -ljpeg
 *   cd $FACERECON_SHARED/data/faces-300w && for f in $(find . -name '*.jpg'); do
 *     mkdir -p /tmp/ppm/$(dirname $f); /tmp/libjpeg_to_ppm $f /tmp/ppm/${f%.jpg}.ppm; done
 *   FACERECON_LIBJPEG_PPM_DIR=/tmp/ppm cargo test -p facerecon-vision --release \
 *     --test dlib_fidelity -- --ignored decoder_equals --nocapture
 */
#include <stdio.h>
#include <stdlib.h>
#include <jpeglib.h>
int main(int argc, char**argv){
  FILE*f=fopen(argv[1],"rb"); struct jpeg_decompress_struct c; struct jpeg_error_mgr e;
  c.err=jpeg_std_error(&e); jpeg_create_decompress(&c); jpeg_stdio_src(&c,f); jpeg_read_header(&c,TRUE);
  c.out_color_space=JCS_RGB; jpeg_start_decompress(&c);
  FILE*o=fopen(argv[2],"wb"); fprintf(o,"P6\n%d %d\n255\n",c.output_width,c.output_height);
  unsigned char*row=malloc(c.output_width*3);
  while(c.output_scanline<c.output_height){jpeg_read_scanlines(&c,&row,1); fwrite(row,1,c.output_width*3,o);}
  jpeg_finish_decompress(&c); fclose(o); return 0;}
