//! The front end (DESIGN §3): from encoded image bytes to faces with a box, 68 landmarks,
//! a 224×224 crop and a resolution bucket each.
