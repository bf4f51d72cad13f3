//! The scene ℋ (DESIGN §4, thesis Eq. 3.1–3.3): pose, perspective camera, SH lighting,
//! vertex normals and projection to pixels.
