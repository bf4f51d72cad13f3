pub mod faces300w;
