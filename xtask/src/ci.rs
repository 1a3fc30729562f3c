//! placeholder
pub fn main(_a: &[String]) -> Result<i32, String> {
    Err("todo".into())
}
